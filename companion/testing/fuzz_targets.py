"""The two running fuzz targets: a SITL process, and the companion's pymavlink link.

Each runs :func:`~companion.testing.fuzz.fuzz_udp` against the real thing over loopback UDP
and then checks what the target did: the SITL must still be disarmed on the ground and answer
(its memory is reported); the link must still be alive, with only finite values in its
snapshot and only in-range MANUAL_CONTROL handed on.
"""

from __future__ import annotations

import math
import os
import socket
from typing import Any

from pymavlink.dialects.v20 import common as M

from companion.config import LinkConfig
from companion.link.mavlink_link import MavlinkLink
from companion.simulator import SimulatorClient, start_sitl
from companion.testing.fuzz import FuzzReport, fuzz_udp, retrying, wait_for

PROBE_COMMAND = M.MAV_CMD_USER_1  # unsupported, so answered UNSUPPORTED; the fuzz never sends it


def rss_kib(pid: int) -> int:
    """Resident memory of a process (Linux /proc), 0 where unknown."""
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1])
    except OSError:
        pass
    return 0


class _Driver:
    """The socket the SITL sends telemetry to; it also sends the fuzz and the probes."""

    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.setblocking(False)
        self.port = self.sock.getsockname()[1]
        self.parser = M.MAVLink(None, 0, 0)
        self.parser.robust_parsing = True
        self.mav = M.MAVLink(None, 250, 190)
        self.peer: tuple[str, int] | None = None
        self.acks: list[Any] = []

    def drain(self) -> None:
        while True:
            try:
                data, addr = self.sock.recvfrom(65535)
            except (BlockingIOError, InterruptedError):
                return
            self.peer = addr
            for m in self.parser.parse_buffer(data) or []:
                if m.get_type() == "COMMAND_ACK" and m.command == PROBE_COMMAND:
                    self.acks.append(m)

    def probe(self, timeout_s: float) -> bool:
        peer = self.peer
        assert peer is not None
        self.acks.clear()

        def send() -> None:
            self.sock.sendto(M.MAVLink_command_long_message(1, 1, PROBE_COMMAND, 0, 0, 0, 0, 0, 0, 0, 0).pack(self.mav), peer)

        def answered() -> bool:
            self.drain()
            return bool(self.acks)

        return retrying(send, answered, timeout_s)


def fuzz_sitl(count: int, seed: int = 0, probe_timeout_s: float = 5.0) -> tuple[FuzzReport, dict[str, Any]]:
    """Fuzz a fresh real-time SITL process; the report and what the vehicle looked like after."""
    driver = _Driver()
    sitl = start_sitl(driver.port, clock="realtime", camera=False, nice=0)
    try:
        def heard() -> bool:
            driver.drain()
            return driver.peer is not None

        wait_for(heard, 10.0)
        if driver.peer is None:
            raise RuntimeError("the SITL sent no telemetry")
        driver.probe(probe_timeout_s)
        rss0 = rss_kib(sitl.proc.pid)
        report = fuzz_udp(driver.peer, count, seed, lambda: driver.probe(probe_timeout_s),
                          lambda: sitl.proc.poll() is None, sock=driver.sock)
        after: dict[str, Any] = {"rss_kib_before": rss0, "rss_kib_after": rss_kib(sitl.proc.pid)}
        if sitl.proc.poll() is None:
            sim = SimulatorClient("127.0.0.1", sitl.control_port)
            try:
                truth = sim.truth()
            finally:
                sim.close()
            after.update(armed=truth["armed"], landed=truth["landed"], mode=truth["mode"],
                         vehicle_ned=truth["vehicle_ned"], vehicle_vel_ned=truth["vehicle_vel_ned"])
        return report, after
    finally:
        sitl.stop()
        driver.sock.close()


class _FakeAutopilot:
    """Just enough of a vehicle for a link to adopt it: HEARTBEATs from system 1."""

    def __init__(self, link_port: int) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.addr = ("127.0.0.1", link_port)
        self.mav = M.MAVLink(None, 1, 1)
        self.stamp_ms = 1000

    def heartbeat(self) -> None:
        hb = M.MAVLink_heartbeat_message(M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_PX4, 0, 0, M.MAV_STATE_STANDBY, 3)
        self.sock.sendto(hb.pack(self.mav), self.addr)

    def marker(self) -> int:
        self.stamp_ms += 1
        self.sock.sendto(M.MAVLink_system_time_message(0, self.stamp_ms).pack(self.mav), self.addr)
        return self.stamp_ms


def fuzz_link(count: int, seed: int = 0, probe_timeout_s: float = 5.0) -> tuple[FuzzReport, dict[str, Any]]:
    """Fuzz the companion's pymavlink link (its I/O thread) in this process."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = int(s.getsockname()[1])
    link = MavlinkLink(LinkConfig(connection=f"udpin:127.0.0.1:{port}", request_rates_on_connect=False,
                                  heartbeat_timeout_s=10.0))
    vehicle = _FakeAutopilot(port)
    manual: list[Any] = []
    try:
        link._io.start()
        retrying(vehicle.heartbeat, lambda: link.state() is not None, 10.0)
        link.connect(timeout_s=5.0)
        link.on_manual_control(manual.append)

        stamp = [0]

        def send() -> None:
            vehicle.heartbeat()
            stamp[0] = vehicle.marker()

        def probe() -> bool:
            return retrying(send, lambda: (s := link.state()) is not None and s.frame_time_boot_ms == stamp[0],
                            probe_timeout_s)

        def alive() -> bool:
            thread = link._io._thread
            return thread is not None and thread.is_alive() and link.stats().thread_errors == 0

        rss0 = rss_kib(os.getpid())
        # from the vehicle's own system id, so that fuzzed telemetry reaches the snapshot
        report = fuzz_udp(vehicle.addr, count, seed, probe, alive, sock=vehicle.sock, system_id=1)
        snap = link.state()
        values = [] if snap is None else [*snap.position_ned_m, *snap.velocity_ned_m_s, *snap.attitude_rad, *snap.rates_frd_rad_s]
        after = {
            "rss_kib_before": rss0, "rss_kib_after": rss_kib(os.getpid()),
            "snapshot_finite": all(math.isfinite(v) for v in values),
            "manual_control_handed_on": len(manual),
            "manual_control_in_range": all(_in_range(v) for v in manual),
            "stats": link.stats().__dict__,
        }
        return report, after
    finally:
        link.close()
        vehicle.sock.close()


def _in_range(value: Any) -> bool:
    axes = [value.axis(name) for name in ("x", "y", "z", "r")]
    return all(a is None or (math.isfinite(a) and -1.0 <= a <= 1.0) for a in axes)
