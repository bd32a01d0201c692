"""The default :class:`VehicleLink`: pymavlink, one I/O thread, immutable snapshots.

The I/O thread reads every message, folds vehicle telemetry into a new snapshot, hands
MANUAL_CONTROL to a registered callback, feeds waiters (COMMAND_ACK, PARAM_VALUE), writes the
tlog and sends our own HEARTBEAT. Caller threads send commands and setpoints under a send
lock; they never touch the parser.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

from companion.config import LinkConfig
from companion.errors import CommandRejected, LinkLost, LinkTimeout
from companion.link import px4_modes
from companion.link.base import (
    LinkStats,
    ManualControlCallback,
    SetpointLimits,
    VehicleLink,
    VehicleSnapshot,
)
from companion.link.connection import open_mavlink, parse_connection
from companion.link.manual_control import parse_manual_control
from companion.link.telemetry import (
    InvalidTelemetry,
    apply_message,
    initial_snapshot,
    is_vehicle_heartbeat,
)
from companion.link.tlog import TlogWriter
from companion.link.waiters import Waiters
from companion.setpoints import VelocitySetpoint

log = logging.getLogger(__name__)

BODY_VELOCITY_TYPE_MASK = 0x5C7  # use vx, vy, vz, yaw rate; ignore position, acceleration, yaw
POSITION_TYPE_MASK = 0x9F8  # use x, y, z, yaw; ignore velocity, acceleration, yaw rate
UINT32_MAX = 2**32 - 1
NAN = float("nan")  # MAVLink's "not set / use current" in command parameters


def result_name(result: int) -> str:
    entry = mavlink.enums["MAV_RESULT"].get(result)
    return entry.name.removeprefix("MAV_RESULT_") if entry else f"UNKNOWN({result})"


def command_name(command: int) -> str:
    entry = mavlink.enums["MAV_CMD"].get(command)
    return entry.name if entry else f"MAV_CMD({command})"


class MavlinkLink(VehicleLink):
    """pymavlink implementation; ``tlog_path`` records both directions as MAVProxy does."""

    def __init__(
        self,
        cfg: LinkConfig,
        tlog_path: str | Path | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.cfg = cfg
        self._spec = parse_connection(cfg.connection, cfg.baud)
        self._limits = SetpointLimits(
            cfg.setpoint_max_speed_m_s, cfg.setpoint_max_yaw_rate_rad_s, cfg.setpoint_max_distance_m
        )
        self._clock = clock
        self._tlog = TlogWriter(tlog_path) if tlog_path is not None else None
        self._conn: Any = None
        self._snapshot: VehicleSnapshot | None = None
        self._target: tuple[int, int] | None = None
        self._vehicle_type = 0
        self._last_heard_s: float | None = None
        self._was_alive = False
        self._changed = threading.Condition()
        self._send_lock = threading.Lock()
        self._command_lock = threading.Lock()
        self._waiters = Waiters()
        self._manual_cb: ManualControlCallback | None = None
        self._counts: Counter[str] = Counter()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # ================================================================ lifecycle
    def connect(self, timeout_s: float = 10.0) -> VehicleSnapshot:
        if self._stop.is_set():
            raise LinkLost("this link was closed; open a new one")
        if self._thread is None:
            self._conn = open_mavlink(self._spec, self.cfg.source_system, self.cfg.source_component)
            self._thread = threading.Thread(target=self._run, name="mavlink-link", daemon=True)
            self._thread.start()
        snapshot = self._wait(lambda s: s is not None, timeout_s)
        if snapshot is None:
            raise LinkTimeout(
                f"no autopilot HEARTBEAT on {self.cfg.connection} within {timeout_s} s; check the "
                "connection string (udpin listens, udpout/tcp connect), the baud rate and that "
                "the vehicle or SITL is running"
            )
        if self.cfg.request_rates_on_connect:
            self.request_rates()
        return snapshot

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)
        if self._conn is not None:
            self._conn.close()
            self._conn = None
        if self._tlog is not None:
            self._tlog.close()
        with self._changed:
            self._changed.notify_all()

    # ================================================================ state
    def state(self) -> VehicleSnapshot | None:
        return self._snapshot

    def link_alive(self) -> bool:
        heard = self._last_heard_s
        return heard is not None and self._clock() - heard < self.cfg.link_lost_s

    def stats(self) -> LinkStats:
        return LinkStats(**dict(self._counts))

    def on_manual_control(self, callback: ManualControlCallback | None) -> None:
        self._manual_cb = callback

    def wait_frame(self, after_time_boot_ms: int, timeout_s: float) -> VehicleSnapshot | None:
        def newer(s: VehicleSnapshot | None) -> bool:
            return s is not None and (s.frame_time_boot_ms or -1) > after_time_boot_ms

        self._require_alive()
        return self._wait(newer, timeout_s, raise_on_loss=True)

    def _wait(
        self,
        ready: Callable[[VehicleSnapshot | None], bool],
        timeout_s: float,
        raise_on_loss: bool = False,
    ) -> VehicleSnapshot | None:
        deadline = self._clock() + timeout_s
        with self._changed:
            while not ready(self._snapshot):
                remaining = deadline - self._clock()
                if remaining <= 0 or self._stop.is_set():
                    return None
                if raise_on_loss and not self.link_alive():
                    raise self._lost_error()
                self._changed.wait(min(remaining, 0.05))
            return self._snapshot

    # ================================================================ commands
    def arm(self) -> None:
        self._command(
            mavlink.MAV_CMD_COMPONENT_ARM_DISARM,
            [1.0],
            "arm",
            "read the vehicle's STATUSTEXT pre-arm messages, fix them and retry",
        )

    def disarm(self) -> None:
        self._command(
            mavlink.MAV_CMD_COMPONENT_ARM_DISARM,
            [0.0],
            "disarm",
            "the vehicle refuses to disarm in the air; land first",
        )

    def set_mode(self, name: str) -> None:
        base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        snapshot = self._require_alive()
        if snapshot.armed:
            base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        if snapshot.autopilot == "PX4":
            main, sub = px4_modes.encode(name)
            params = [float(base), float(main), float(sub)]
        else:
            params = [float(base), float(self._other_mode_number(name))]
        self._command(
            mavlink.MAV_CMD_DO_SET_MODE,
            params,
            f"set_mode({name!r})",
            "OFFBOARD needs a setpoint stream first; AUTO modes need a position estimate",
        )

    def _other_mode_number(self, name: str) -> int:
        from pymavlink import mavutil

        mapping = mavutil.mode_mapping_byname(self._vehicle_type) or {}
        if name.upper() not in mapping:
            raise CommandRejected(
                f"set_mode({name!r})", "UNSUPPORTED", f"this autopilot knows {sorted(mapping)}"
            )
        return int(mapping[name.upper()])

    def takeoff(self, alt_m: float) -> None:
        if not (math.isfinite(alt_m) and 0.0 < alt_m <= self.cfg.takeoff_max_alt_m):
            raise ValueError(
                f"takeoff altitude {alt_m} m must be in (0, {self.cfg.takeoff_max_alt_m}] "
                "(companion.link.takeoff_max_alt_m)"
            )
        snapshot = self._require_alive()
        if snapshot.autopilot == "PX4":
            # As MAVSDK does: PX4 takes the altitude from MIS_TAKEOFF_ALT (param7 is AMSL).
            self._set_param("MIS_TAKEOFF_ALT", alt_m)
            params = [-1.0, 0.0, 0.0, NAN, NAN, NAN, NAN]
        else:
            params = [0.0, 0.0, 0.0, NAN, 0.0, 0.0, float(alt_m)]
        self._command(
            mavlink.MAV_CMD_NAV_TAKEOFF,
            params,
            "takeoff",
            "arm first, and make sure the vehicle has a position estimate",
        )

    def land(self) -> None:
        self._command(mavlink.MAV_CMD_NAV_LAND, [0.0, 0.0, 0.0, NAN, NAN, NAN, NAN], "land")

    def request_rates(self, rates_hz: Mapping[str, float] | None = None) -> dict[str, str]:
        """Send MAV_CMD_SET_MESSAGE_INTERVAL per message; a refusal is reported, not raised."""
        if rates_hz is None:
            rates_hz = self.default_rates_hz()
        results: dict[str, str] = {}
        for name, hz in rates_hz.items():
            msg_id = getattr(mavlink, f"MAVLINK_MSG_ID_{name}", None)
            if msg_id is None or not math.isfinite(hz) or hz < 0:
                raise ValueError(f"cannot request {name} at {hz} Hz: unknown message or bad rate")
            interval_us = 1e6 / hz if hz > 0 else -1.0
            try:
                self._command(
                    mavlink.MAV_CMD_SET_MESSAGE_INTERVAL,
                    [float(msg_id), interval_us],
                    f"SET_MESSAGE_INTERVAL({name})",
                    retries=0,
                )
                results[name] = "ACCEPTED"
            except CommandRejected as exc:
                results[name] = exc.result
            except LinkTimeout:
                results[name] = "TIMEOUT"
            if results[name] != "ACCEPTED":
                log.warning("vehicle did not accept %s at %.1f Hz: %s", name, hz, results[name])
        return results

    def default_rates_hz(self) -> dict[str, float]:
        """What the companion needs: fast attitude and position, slower landed state."""
        fast, slow = self.cfg.telemetry_rate_hz, self.cfg.status_rate_hz
        rates = {"ATTITUDE": fast, "LOCAL_POSITION_NED": fast, "EXTENDED_SYS_STATE": slow}
        return {name: hz for name, hz in rates.items() if hz > 0}

    def _command(
        self,
        command: int,
        params: Sequence[float],
        name: str,
        hint: str = "",
        retries: int | None = None,
    ) -> None:
        """COMMAND_LONG, waiting for its COMMAND_ACK; resent up to ``retries`` times."""
        self._require_alive()
        tsys, tcomp = self._target  # type: ignore[misc]
        padded = (list(params) + [0.0] * 7)[:7]
        attempts = 1 + (self.cfg.command_retries if retries is None else retries)
        with self._command_lock:
            waiter = self._waiters.add(
                lambda m: m.get_type() == "COMMAND_ACK" and m.command == command
            )
            try:
                for attempt in range(attempts):
                    self._send(
                        self._mav.command_long_encode(
                            tsys, tcomp, command, min(attempt, 255), *padded
                        )
                    )
                    if self._await_ack(waiter, name, hint):
                        return
                    self._require_alive()
            finally:
                self._waiters.remove(waiter)
        raise LinkTimeout(
            f"{name}: no COMMAND_ACK after {attempts} attempt(s) of {self.cfg.command_timeout_s} s "
            f"({command_name(command)}); the vehicle may not support it, or the link drops replies"
        )

    def _await_ack(self, waiter: Any, name: str, hint: str) -> bool:
        deadline = self._clock() + self.cfg.command_timeout_s
        while (remaining := deadline - self._clock()) > 0:
            ack = waiter.get(remaining)
            if ack is None:
                return False
            if ack.result == mavlink.MAV_RESULT_IN_PROGRESS:
                deadline = self._clock() + self.cfg.command_timeout_s
                continue
            if ack.result == mavlink.MAV_RESULT_ACCEPTED:
                return True
            raise CommandRejected(name, result_name(ack.result), hint)
        return False

    def _set_param(self, name: str, value: float) -> None:
        """PARAM_SET, waiting briefly for the PARAM_VALUE echo (logged if it never comes)."""
        tsys, tcomp = self._target  # type: ignore[misc]
        waiter = self._waiters.add(lambda m: m.get_type() == "PARAM_VALUE" and m.param_id == name)
        try:
            self._send(
                self._mav.param_set_encode(
                    tsys, tcomp, name.encode(), float(value), mavlink.MAV_PARAM_TYPE_REAL32
                )
            )
            if waiter.get(self.cfg.command_timeout_s) is None:
                log.warning("no PARAM_VALUE echo for %s=%s; continuing", name, value)
        finally:
            self._waiters.remove(waiter)

    # ================================================================ setpoints
    def send_velocity_body(
        self, sp: VelocitySetpoint, echo_time_boot_ms: int | None = None
    ) -> None:
        self._limits.check_velocity(sp)
        snapshot = self._require_alive()
        stamp = self._stamp(snapshot, echo_time_boot_ms)
        tsys, tcomp = self._target  # type: ignore[misc]
        self._send(
            self._mav.set_position_target_local_ned_encode(
                stamp,
                tsys,
                tcomp,
                mavlink.MAV_FRAME_BODY_NED,
                BODY_VELOCITY_TYPE_MASK,
                0.0,
                0.0,
                0.0,
                sp.forward_m_s,
                sp.right_m_s,
                sp.down_m_s,
                0.0,
                0.0,
                0.0,
                0.0,
                sp.yaw_rate_rad_s,
            )
        )
        self._counts["setpoints_sent"] += 1

    def send_position_ned(
        self,
        north_m: float,
        east_m: float,
        down_m: float,
        yaw_rad: float,
        echo_time_boot_ms: int | None = None,
    ) -> None:
        self._limits.check_position(north_m, east_m, down_m, yaw_rad)
        snapshot = self._require_alive()
        stamp = self._stamp(snapshot, echo_time_boot_ms)
        tsys, tcomp = self._target  # type: ignore[misc]
        self._send(
            self._mav.set_position_target_local_ned_encode(
                stamp,
                tsys,
                tcomp,
                mavlink.MAV_FRAME_LOCAL_NED,
                POSITION_TYPE_MASK,
                float(north_m),
                float(east_m),
                float(down_m),
                0.0,
                0.0,
                0.0,
                0.0,
                0.0,
                0.0,
                float(yaw_rad),
                0.0,
            )
        )
        self._counts["setpoints_sent"] += 1

    @staticmethod
    def _stamp(snapshot: VehicleSnapshot, echo_time_boot_ms: int | None) -> int:
        """The setpoint's time_boot_ms: the echoed frame, else the newest frame heard."""
        if echo_time_boot_ms is None:
            frame = snapshot.frame_time_boot_ms
            return int(frame if frame is not None else snapshot.time_boot_ms)
        if not 0 <= int(echo_time_boot_ms) <= UINT32_MAX:
            raise ValueError(f"echo_time_boot_ms {echo_time_boot_ms} is not a uint32 ms stamp")
        return int(echo_time_boot_ms)

    # ================================================================ sending
    @property
    def _mav(self) -> Any:
        if self._conn is None:
            raise LinkLost("the link is not open; call connect() first")
        return self._conn.mav

    def _send(self, msg: Any) -> None:
        with self._send_lock:
            conn = self._conn
            if conn is None:
                raise LinkLost("the link is closed; open a new one")
            conn.mav.send(msg)
            if self._tlog is not None:
                self._tlog.write(msg.get_msgbuf(), sent=True)

    def _send_heartbeat(self) -> None:
        try:
            self._send(
                self._mav.heartbeat_encode(
                    mavlink.MAV_TYPE_ONBOARD_CONTROLLER,
                    mavlink.MAV_AUTOPILOT_INVALID,
                    0,
                    0,
                    mavlink.MAV_STATE_ACTIVE,
                )
            )
        except (OSError, LinkLost):
            self._counts["thread_errors"] += 1

    def _require_alive(self) -> VehicleSnapshot:
        snapshot = self._snapshot
        if snapshot is None or self._target is None:
            raise LinkLost("no vehicle heard yet; call connect() first")
        if self._stop.is_set():
            raise LinkLost("the link is closed; open a new one")
        if not self.link_alive():
            raise self._lost_error()
        return snapshot

    def _lost_error(self) -> LinkLost:
        return LinkLost(
            f"nothing heard from the vehicle for more than {self.cfg.link_lost_s} s on "
            f"{self.cfg.connection}; the link keeps listening and resumes by itself - hold, "
            "check the radio or cable, and retry when link_alive() is True"
        )

    # ================================================================ I/O thread
    def _run(self) -> None:
        next_heartbeat = self._clock()
        while not self._stop.is_set():
            now = self._clock()
            if now >= next_heartbeat:
                self._send_heartbeat()
                next_heartbeat = now + self.cfg.heartbeat_period_s
            self._track_liveness()
            try:
                msg = self._conn.recv_msg()
                if msg is None:
                    self._conn.select(min(0.02, max(0.0, next_heartbeat - now)))
                    continue
                self._handle(msg)
            except Exception:  # noqa: BLE001 - the I/O thread must outlive any bad input
                self._counts["thread_errors"] += 1
                log.exception("MAVLink I/O thread error (continuing)")
                time.sleep(0.01)

    def _track_liveness(self) -> None:
        alive = self.link_alive()
        if self._was_alive and not alive:
            self._counts["link_losses"] += 1
            log.warning("MAVLink link lost: nothing heard for %.1f s", self.cfg.link_lost_s)
            with self._changed:
                self._changed.notify_all()
        self._was_alive = alive

    def _handle(self, msg: Any) -> None:
        kind = msg.get_type()
        if kind == "BAD_DATA":
            self._counts["bad_data"] += 1
            return
        self._counts["messages_received"] += 1
        if self._tlog is not None:
            self._tlog.write(msg.get_msgbuf())
        now = self._clock()
        if kind == "MANUAL_CONTROL":
            self._manual_control(msg, now)
            return
        if self._target is None:
            if is_vehicle_heartbeat(msg):
                self._adopt_vehicle(msg, now)
            return
        if msg.get_srcSystem() != self._target[0]:
            return
        self._heard(now)
        self._waiters.offer(msg)
        self._fold(msg, now)

    def _adopt_vehicle(self, msg: Any, now: float) -> None:
        self._target = (msg.get_srcSystem(), msg.get_srcComponent())
        self._vehicle_type = int(msg.type)
        self._heard(now)
        self._publish(initial_snapshot(msg, now))
        log.info("vehicle found: system %d component %d", *self._target)

    def _heard(self, now: float) -> None:
        if self._last_heard_s is not None and not self.link_alive():
            self._counts["reconnections"] += 1
            log.warning("MAVLink link back after loss")
        self._last_heard_s = now
        self._was_alive = True

    def _fold(self, msg: Any, now: float) -> None:
        snapshot = self._snapshot
        if snapshot is None:
            return
        try:
            new = apply_message(snapshot, msg, now, self.cfg.frame_marker)
        except InvalidTelemetry:
            self._counts["telemetry_rejected"] += 1
            return
        self._publish(new)

    def _publish(self, snapshot: VehicleSnapshot) -> None:
        with self._changed:
            self._snapshot = snapshot
            self._changed.notify_all()

    def _manual_control(self, msg: Any, now: float) -> None:
        self._counts["manual_control_received"] += 1
        targets = {0, self.cfg.source_system}
        if self._target is not None:
            targets.add(self._target[0])
        if msg.target not in targets:
            return
        value = parse_manual_control(msg, now)
        if value is None:
            self._counts["manual_control_dropped"] += 1
            log.warning(
                "MANUAL_CONTROL from %d with out-of-range axes dropped", msg.get_srcSystem()
            )
            return
        callback = self._manual_cb
        if callback is None:
            return
        try:
            callback(value)
        except Exception:  # noqa: BLE001 - a faulty consumer must not kill the link
            self._counts["callback_errors"] += 1
            log.exception("manual-control callback failed")
