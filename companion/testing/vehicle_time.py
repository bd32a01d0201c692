"""The vehicle's own time, for scripts and tests that wait on what a vehicle does.

An autopilot's SITL may run faster than real time (PX4 SIH ``PX4_SIM_SPEED_FACTOR``, ArduCopter
``--speedup``, our SITL ``--speed``), so "descend for 20 s" or "disarmed within 40 s" must count
the vehicle's seconds, not the wall's, to mean the same at any speed-up. The vehicle's seconds
come from the ``time_boot_ms`` of the messages it sends (:class:`VehicleClock`), from a live
connection or from the companion's growing ``session.tlog`` (:class:`TlogClock`). The wall
clock stays only as a safety limit (:func:`wall_cap_s`): a vehicle that stops talking stops its
clock too.
"""

from __future__ import annotations

import struct
from pathlib import Path
from typing import Any

from pymavlink import mavutil

from companion.link.tlog import RECEIVED_LINK

REBOOT_JUMP_MS = 5000  # a stamp this far behind the last one: the vehicle rebooted (its boot clock restarts)
WALL_CAP_FACTOR = 3.0
WALL_CAP_SLACK_S = 10.0


def wall_cap_s(vehicle_s: float) -> float:
    """The most wall time to give ``vehicle_s`` of the vehicle's time before giving up.

    At a speed-up of 1 or more an idle machine passes ``vehicle_s`` in at most as much wall time;
    a loaded one (CI: load ~10 on 2 cores) slows the vehicle down, so allow three times that and
    a start-up's worth more. Only a failure ever waits this long."""
    return WALL_CAP_FACTOR * vehicle_s + WALL_CAP_SLACK_S


class VehicleClock:
    """Seconds of a vehicle's boot clock heard so far, monotonic across its reboots.

    Messages arrive slightly out of stamp order (each stream is stamped when it is made), so a
    stamp behind the newest is ignored; one more than :data:`REBOOT_JUMP_MS` behind is a reboot,
    from which the clock counts on."""

    def __init__(self) -> None:
        self.seconds = 0.0
        self.heard = False
        self._last_ms: int | None = None

    def observe(self, msg: Any) -> None:
        """Fold one message from the vehicle (any message with a ``time_boot_ms``)."""
        ms = getattr(msg, "time_boot_ms", None)
        if not isinstance(ms, int):
            return
        if self._last_ms is not None and ms >= self._last_ms:
            self.seconds += (ms - self._last_ms) / 1000.0
        if self._last_ms is None or ms > self._last_ms or self._last_ms - ms > REBOOT_JUMP_MS:
            self._last_ms = ms
        self.heard = True


def _packet_length(buf: bytes, at: int) -> int | None:
    """Length of the MAVLink packet starting at ``buf[at]`` (None: its header is not all there)."""
    if len(buf) < at + 3:
        return None
    magic, payload = buf[at], buf[at + 1]
    if magic == mavutil.mavlink.PROTOCOL_MARKER_V2:
        return 12 + payload + (13 if buf[at + 2] & mavutil.mavlink.MAVLINK_IFLAG_SIGNED else 0)
    if magic == mavutil.mavlink.PROTOCOL_MARKER_V1:
        return 8 + payload
    return 1  # not a packet: skip the byte (never seen in the companion's own tlogs)


class TlogClock:
    """The vehicle's time as the companion's ``session.tlog`` (companion/link/tlog.py) has it
    so far, read on as the file grows: a test can wait on the vehicle's time while ``col`` flies
    it, without a second listener on the vehicle's port."""

    def __init__(self, path: Path, component: int = 1) -> None:
        self.path, self.component = path, component
        self.clock = VehicleClock()
        self.wall_first_s: float | None = None  # the tlog's own arrival stamps (Unix time) of the vehicle's packets
        self.wall_last_s: float | None = None
        self.vehicle_first_s: float | None = None
        self._offset = 0
        self._buf = b""
        self._parser = mavutil.mavlink.MAVLink(None)
        self._parser.robust_parsing = True

    def seconds(self) -> float:
        """The vehicle's seconds heard up to the end of the file as it is now."""
        try:
            with self.path.open("rb") as f:
                f.seek(self._offset)
                chunk = f.read()
        except FileNotFoundError:
            return self.clock.seconds
        self._offset += len(chunk)
        self._buf += chunk
        self._buf = self._buf[self._fold_records():]
        return self.clock.seconds

    def _fold_records(self) -> int:
        """Fold every complete record in the buffer; how many bytes were used."""
        at = 0
        while (n := _packet_length(self._buf, at + 8)) is not None and len(self._buf) >= at + 8 + n:
            (usec,) = struct.unpack(">Q", self._buf[at:at + 8])
            if usec & 3 == RECEIVED_LINK and n > 1:
                for msg in self._parser.parse_buffer(self._buf[at + 8:at + 8 + n]) or []:
                    self._fold(msg, usec / 1e6)
            at += 8 + n
        return at

    def _fold(self, msg: Any, wall_s: float) -> None:
        if msg.get_srcComponent() != self.component or not hasattr(msg, "time_boot_ms"):
            return
        self.clock.observe(msg)
        if self.wall_first_s is None:
            self.wall_first_s, self.vehicle_first_s = wall_s, self.clock.seconds
        self.wall_last_s = wall_s

    def speed(self) -> dict[str, float] | None:
        """Vehicle seconds per wall second over the whole file (read to its end first), with both
        spans: what speed-up the vehicle kept while the companion flew it. None: nothing stamped."""
        vehicle_s = self.seconds()
        if self.wall_first_s is None or self.wall_last_s is None or self.vehicle_first_s is None:
            return None
        wall = self.wall_last_s - self.wall_first_s
        span = vehicle_s - self.vehicle_first_s
        return {"wall_s": round(wall, 2), "vehicle_s": round(span, 2), "speed": round(span / wall, 3) if wall > 0 else 0.0}
