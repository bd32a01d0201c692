"""The default :class:`VehicleLink`: pymavlink, with ACKed commands and streamed setpoints.

The I/O (connection, thread, snapshots, tlog) lives in :mod:`companion.link.mavlink_io`; this
module turns the interface's calls into MAVLink: COMMAND_LONG with COMMAND_ACK wait and
retries, PX4 custom modes, SET_MESSAGE_INTERVAL, and SET_POSITION_TARGET_LOCAL_NED.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pymavlink.dialects.v20 import ardupilotmega
from pymavlink.dialects.v20 import common as mavlink

import companion.link.px4_modes as px4_modes
from companion.config import LinkConfig
from companion.errors import CommandRejected, LinkError, LinkLost, LinkTimeout
from companion.link.base import LinkStats, ManualControlCallback, SetpointLimits, VehicleLink
from companion.link.connection import parse_connection
from companion.link.dialect import PX4, Dialect, dialect_for
from companion.link.mavlink_io import MavlinkIO
from companion.link.waiters import Waiter
from companion.msg.setpoint import VelocitySetpoint
from companion.msg.snapshot import VehicleSnapshot

if TYPE_CHECKING:
    from companion.link.landing_target import LandingTarget

log = logging.getLogger(__name__)

STATUSTEXT_GRACE_S = 0.3  # after a refusal: how long the vehicle's reasons may trail its ACK
UINT32_MAX = 2**32 - 1
NAN = float("nan")  # MAVLink's "not set / use current" in command parameters
FORCE_ARM_DISARM = 21196.0  # MAV_CMD_COMPONENT_ARM_DISARM param2: arm or disarm whatever the checks say
# streams a PX4-like vehicle sends by default that no part of the companion reads (HEARTBEAT,
# ATTITUDE, LOCAL_POSITION_NED, EXTENDED_SYS_STATE and SYSTEM_TIME are what it folds)
HOME_POSITION_RATE_HZ = 0.5  # home moves only when the vehicle is armed again; heights are taken from it
UNREAD_STREAMS = ("ATTITUDE_QUATERNION", "GLOBAL_POSITION_INT", "GPS_RAW_INT", "VFR_HUD", "SYS_STATUS",
                  "BATTERY_STATUS")


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
        self._io = MavlinkIO(cfg, parse_connection(cfg.connection, cfg.baud), tlog_path, clock)
        self._limits = SetpointLimits(
            cfg.setpoint_max_speed_m_s, cfg.setpoint_max_yaw_rate_rad_s, cfg.setpoint_max_distance_m
        )
        self._clock = clock
        self._command_lock = threading.Lock()

    # ================================================================ lifecycle and state
    def connect(self, timeout_s: float | None = None) -> VehicleSnapshot:
        timeout_s = self.cfg.heartbeat_timeout_s if timeout_s is None else timeout_s
        self._io.start()
        snapshot = self._io.wait(lambda s: s is not None or self._io.signing_problem() is not None, timeout_s)
        problem = self._io.signing_problem()
        if problem is not None:
            self._io.close()
            raise LinkError(problem)
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
        self._io.close()

    def state(self) -> VehicleSnapshot | None:
        return self._io.snapshot

    def link_alive(self) -> bool:
        return self._io.alive()

    def stats(self) -> LinkStats:
        return self._io.stats()

    def on_manual_control(self, callback: ManualControlCallback | None) -> None:
        self._io.manual_callback = callback

    def wait_frame(self, after_time_boot_ms: int, timeout_s: float) -> VehicleSnapshot | None:
        def newer(s: VehicleSnapshot | None) -> bool:
            return s is not None and (s.frame_time_boot_ms or -1) > after_time_boot_ms

        def lost() -> None:
            raise self._lost_error()

        self._require_alive()
        return self._io.wait(newer, timeout_s, on_loss=lost)

    # ================================================================ commands
    def dialect(self) -> Dialect:
        """The vehicle's autopilot dialect (PX4 until a heartbeat says otherwise)."""
        snapshot = self._io.snapshot
        return PX4 if snapshot is None else dialect_for(snapshot.autopilot)

    def arm(self) -> None:
        self._command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, [1.0], "arm", self.dialect().arm_hint)

    def disarm(self) -> None:
        self._command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, [0.0], "disarm",
                      "the vehicle refuses to disarm in the air; land first")  # fmt: skip

    def force_disarm(self) -> None:
        self._command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, [0.0, FORCE_ARM_DISARM], "force disarm",
                      "the vehicle refused even a forced disarm")  # fmt: skip

    def set_mode(self, name: str) -> None:
        snapshot = self._require_alive()
        base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        if snapshot.armed:
            base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        if snapshot.autopilot == "PX4":
            main, sub = px4_modes.encode(name)
            params = [float(base), float(main), float(sub)]
        else:
            params = [float(base), float(self._other_mode_number(name))]
        hint = ("OFFBOARD needs a setpoint stream first; AUTO modes need a position estimate"
                if snapshot.autopilot == "PX4" else "read the vehicle's messages for why")  # fmt: skip
        self._command(mavlink.MAV_CMD_DO_SET_MODE, params, f"set_mode({name!r})", hint)

    def _other_mode_number(self, name: str) -> int:
        from pymavlink import mavutil

        mapping = mavutil.mode_mapping_byname(self._io.vehicle_type) or {}
        if name.upper() not in mapping:
            raise CommandRejected(
                f"set_mode({name!r})", "UNSUPPORTED", f"this autopilot knows {sorted(mapping)}",
                origin="companion",
            )
        return int(mapping[name.upper()])

    def takeoff(self, alt_m: float) -> None:
        if not (math.isfinite(alt_m) and 0.0 < alt_m <= self.cfg.takeoff_max_alt_m):
            raise ValueError(
                f"takeoff altitude {alt_m} m must be in (0, {self.cfg.takeoff_max_alt_m}] "
                "(companion.link.takeoff_max_alt_m)"
            )
        if self._require_alive().autopilot == "PX4":
            # As MAVSDK does: PX4 takes the altitude from MIS_TAKEOFF_ALT (param7 is AMSL).
            self._set_param("MIS_TAKEOFF_ALT", alt_m)
            params = [-1.0, 0.0, 0.0, NAN, NAN, NAN, NAN]
        else:
            params = [0.0, 0.0, 0.0, NAN, 0.0, 0.0, float(alt_m)]
        self._command(mavlink.MAV_CMD_NAV_TAKEOFF, params, "takeoff", self.dialect().takeoff_hint)

    def land(self) -> None:
        self._command(mavlink.MAV_CMD_NAV_LAND, [0.0, 0.0, 0.0, NAN, NAN, NAN, NAN], "land")

    def reboot(self) -> None:
        """Sent once: a lost ACK is not resent, since the vehicle may already be rebooting."""
        self._command(mavlink.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, [1.0], "reboot",
                      "autopilots reboot only while disarmed: land and disarm first", retries=0)

    def request_rates(self, rates_hz: Mapping[str, float] | None = None) -> dict[str, str]:
        """Send MAV_CMD_SET_MESSAGE_INTERVAL per message; a refusal is reported, not raised."""
        rates_hz = self.default_rates_hz() if rates_hz is None else rates_hz
        results: dict[str, str] = {}
        for name, hz in rates_hz.items():
            params = list(interval_params(name, hz))
            try:
                self._command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, params,
                              f"SET_MESSAGE_INTERVAL({name})", retries=0)  # fmt: skip
                results[name] = "ACCEPTED"
            except CommandRejected as exc:
                results[name] = exc.result
            except LinkTimeout:
                results[name] = "TIMEOUT"
            if results[name] != "ACCEPTED":
                log.warning("vehicle did not accept %s at %.1f Hz: %s", name, hz, results[name])
        return results

    def request_message(
        self, message_name: str, component_id: int = 1, timeout_s: float = 2.0
    ) -> dict[str, Any] | None:
        """REQUEST_MESSAGE to one component; its ACK and reply must come from that component.

        Resent every ``command_timeout_s`` until the component ACKs; a reply without an ACK
        counts too (some components skip it).
        """
        msg_id = message_id(message_name)
        self._require_alive()
        command = mavlink.MAV_CMD_REQUEST_MESSAGE
        deadline = self._clock() + timeout_s
        answers = self._io.waiters.add(
            lambda m: m.get_srcComponent() == component_id
            and (m.get_type() == message_name or (m.get_type() == "COMMAND_ACK" and m.command == command))
        )  # fmt: skip
        try:
            acked, attempt = False, 0
            while (remaining := deadline - self._clock()) > 0:
                if not acked:
                    self._send_command(command, [float(msg_id)], component_id, attempt)
                    attempt += 1
                    remaining = min(self.cfg.command_timeout_s, remaining)
                answer = answers.get(remaining)
                if answer is not None and answer.get_type() == message_name:
                    return message_fields(answer)
                acked = acked or (
                    answer is not None and self._accepted(answer, message_name, component_id)
                )
        finally:
            self._io.waiters.remove(answers)
        log.info("REQUEST_MESSAGE(%s): no answer from component %d within %.1f s",
                 message_name, component_id, timeout_s)  # fmt: skip
        return None

    def _send_command(
        self, command: int, params: Sequence[float], component_id: int, attempt: int
    ) -> None:
        tsys, _ = self._target()
        padded = (list(params) + [0.0] * 7)[:7]
        confirmation = min(attempt, 255)
        self._io.send(
            self._io.mav.command_long_encode(tsys, component_id, command, confirmation, *padded)
        )

    @staticmethod
    def _accepted(ack: Any, message_name: str, component_id: int) -> bool:
        """True for ACCEPTED, False for IN_PROGRESS; CommandRejected for a refusal."""
        if ack.result in (mavlink.MAV_RESULT_ACCEPTED, mavlink.MAV_RESULT_IN_PROGRESS):
            return ack.result == mavlink.MAV_RESULT_ACCEPTED
        raise CommandRejected(
            f"REQUEST_MESSAGE({message_name}) to component {component_id}",
            result_name(ack.result),
            "the component does not offer this message",
        )

    def default_rates_hz(self) -> dict[str, float]:
        """What the companion needs: fast attitude and position, slower landed state."""
        return default_rates_hz(self.cfg)

    def _command(
        self, command: int, params: Sequence[float], name: str, hint: str = "",
        retries: int | None = None,
    ) -> None:  # fmt: skip
        """COMMAND_LONG, waiting for its COMMAND_ACK; resent up to ``retries`` times."""
        self._require_alive()
        tsys, tcomp = self._target()
        padded = (list(params) + [0.0] * 7)[:7]
        attempts = 1 + (self.cfg.command_retries if retries is None else retries)
        with self._command_lock:
            waiter = self._io.waiters.add(
                lambda m: m.get_type() == "COMMAND_ACK" and m.command == command
            )
            texts = self._io.waiters.add(_is_complaint)
            try:
                for attempt in range(attempts):
                    confirmation = min(attempt, 255)
                    self._io.send(
                        self._io.mav.command_long_encode(
                            tsys, tcomp, command, confirmation, *padded
                        )
                    )
                    if self._await_ack(waiter, name, hint, texts):
                        return
                    self._require_alive()
            finally:
                self._io.waiters.remove(waiter)
                self._io.waiters.remove(texts)
        raise LinkTimeout(
            f"{name}: no COMMAND_ACK after {attempts} attempt(s) of {self.cfg.command_timeout_s} s "
            f"({command_name(command)}); the vehicle may not support it, or the link drops replies"
        )

    def _await_ack(self, waiter: Waiter, name: str, hint: str, texts: Waiter) -> bool:
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
            raise CommandRejected(name, result_name(ack.result), hint, reasons=self._reasons(texts))
        return False

    def _reasons(self, texts: Waiter) -> tuple[str, ...]:
        """The vehicle's STATUSTEXT complaints around a refusal (before its ACK or just after)."""
        found: list[str] = []
        deadline = self._clock() + STATUSTEXT_GRACE_S
        while (remaining := deadline - self._clock()) > 0:
            msg = texts.get(min(remaining, 0.1))
            if msg is None:
                break
            found.append(str(msg.text).rstrip("\x00").strip())
        return tuple(dict.fromkeys(t for t in found if t))

    def read_param(self, name: str, timeout_s: float | None = None) -> float | None:
        """PARAM_REQUEST_READ by name, asked again every ``command_timeout_s`` until a
        PARAM_VALUE of that name comes (None after ``timeout_s``; by default as many tries as a
        command gets: a loaded autopilot's reply can be lost or late, as a command's ACK can)."""
        self._require_alive()
        tsys, tcomp = self._target()
        budget = self._param_budget_s(timeout_s)
        value = self._param_exchange(name, lambda: self._io.mav.param_request_read_encode(tsys, tcomp, name.encode(), -1),
                                     budget, lambda reply: math.isfinite(reply.param_value))
        if value is None:
            log.info("the vehicle did not answer PARAM_REQUEST_READ(%s) within %.1f s", name, budget)
        return value

    def set_param(self, name: str, value: float, timeout_s: float | None = None) -> float | None:
        """PARAM_SET, sent again every ``command_timeout_s`` until PARAM_VALUE echoes the name
        (None after ``timeout_s``, by default as many tries as a command gets). Setting a value
        twice is harmless, so a lost echo is simply asked for again."""
        self._require_alive()
        tsys, tcomp = self._target()
        return self._param_exchange(name, lambda: self._io.mav.param_set_encode(
            tsys, tcomp, name.encode(), float(value), mavlink.MAV_PARAM_TYPE_REAL32),
            self._param_budget_s(timeout_s), lambda reply: True)

    def _param_budget_s(self, timeout_s: float | None) -> float:
        return self.cfg.command_timeout_s * (1 + self.cfg.command_retries) if timeout_s is None else timeout_s

    def _param_exchange(self, name: str, request: Callable[[], Any], timeout_s: float,
                        accept: Callable[[Any], bool]) -> float | None:
        """Send ``request()`` every ``command_timeout_s`` until a PARAM_VALUE of ``name`` that
        ``accept`` takes arrives: its value, or None after ``timeout_s``."""
        waiter = self._io.waiters.add(lambda m: m.get_type() == "PARAM_VALUE" and m.param_id == name)
        deadline = self._clock() + timeout_s
        try:
            while (remaining := deadline - self._clock()) > 0:
                self._io.send(request())
                reply = waiter.get(min(self.cfg.command_timeout_s, remaining))
                if reply is not None and accept(reply):
                    return float(reply.param_value)
        finally:
            self._io.waiters.remove(waiter)
        return None

    def send_landing_target(self, target: LandingTarget) -> None:
        self._require_alive()
        self._io.send(self._io.mav.landing_target_encode(*target.encode_args()))

    def _set_param(self, name: str, value: float) -> None:
        """PARAM_SET, waiting briefly for the PARAM_VALUE echo (logged if it never comes)."""
        tsys, tcomp = self._target()
        waiter = self._io.waiters.add(
            lambda m: m.get_type() == "PARAM_VALUE" and m.param_id == name
        )
        try:
            real32 = mavlink.MAV_PARAM_TYPE_REAL32
            self._io.send(
                self._io.mav.param_set_encode(tsys, tcomp, name.encode(), float(value), real32)
            )
            if waiter.get(self.cfg.command_timeout_s) is None:
                log.warning("no PARAM_VALUE echo for %s=%s; continuing", name, value)
        finally:
            self._io.waiters.remove(waiter)

    # ================================================================ setpoints
    def send_velocity_body(
        self, sp: VelocitySetpoint, echo_time_boot_ms: int | None = None
    ) -> None:
        self._limits.check_velocity(sp)
        stamp = _stamp(self._require_alive(), echo_time_boot_ms)
        d = self.dialect()
        self._send_target(
            stamp, d.body_frame, d.body_type_mask,
            (0.0, 0.0, 0.0), (sp.forward_m_s, sp.right_m_s, sp.down_m_s), 0.0, sp.yaw_rate_rad_s,
        )  # fmt: skip

    def send_position_ned(
        self, north_m: float, east_m: float, down_m: float, yaw_rad: float,
        echo_time_boot_ms: int | None = None,
    ) -> None:  # fmt: skip
        self._limits.check_position(north_m, east_m, down_m, yaw_rad)
        stamp = _stamp(self._require_alive(), echo_time_boot_ms)
        position = (float(north_m), float(east_m), float(down_m))
        d = self.dialect()
        self._send_target(stamp, d.position_frame, d.position_type_mask,
                          position, (0.0, 0.0, 0.0), float(yaw_rad), 0.0)  # fmt: skip

    def _send_target(
        self, stamp: int, frame: int, type_mask: int, position: tuple[float, float, float],
        velocity: tuple[float, float, float], yaw_rad: float, yaw_rate_rad_s: float,
    ) -> None:  # fmt: skip
        tsys, tcomp = self._target()
        msg = self._io.mav.set_position_target_local_ned_encode(
            stamp, tsys, tcomp, frame, type_mask, *position, *velocity, 0.0, 0.0, 0.0,
            yaw_rad, yaw_rate_rad_s,
        )  # fmt: skip
        self._io.send(msg)
        self._io.counts["setpoints_sent"] += 1

    def send_statustext(self, text: str, severity: int = 4) -> bool:
        """STATUSTEXT from the companion's component; the autopilot forwards it to the ground
        stations (PX4 with MAVLink forwarding on; our SITL always)."""
        self._require_alive()
        self._io.send(self._io.mav.statustext_encode(int(severity), text.encode("ascii", "replace")[:50]))
        return True

    # ================================================================ guards
    def _target(self) -> tuple[int, int]:
        target = self._io.target
        if target is None:
            raise LinkLost("no vehicle heard yet; call connect() first")
        return target

    def _require_alive(self) -> VehicleSnapshot:
        snapshot = self._io.snapshot
        if self._io.closed:
            raise LinkLost("the link is closed; open a new one")
        if snapshot is None or self._io.target is None:
            raise LinkLost("no vehicle heard yet; call connect() first")
        if not self._io.alive():
            raise self._lost_error()
        return snapshot

    def _lost_error(self) -> LinkLost:
        return LinkLost(
            f"nothing heard from the vehicle for more than {self.cfg.link_lost_s} s on "
            f"{self.cfg.connection}; the link keeps listening and resumes by itself - hold, "
            "check the radio or cable, and retry when link_alive() is True"
        )


def default_rates_hz(cfg: LinkConfig) -> dict[str, float]:
    """The streams the companion asks for on connect (message name -> Hz; 0 stops a stream): fast
    attitude and position, slower landed state."""
    fast, slow = cfg.telemetry_rate_hz, cfg.status_rate_hz
    rates = {"ATTITUDE": fast, "LOCAL_POSITION_NED": fast, "EXTENDED_SYS_STATE": slow,
             "HOME_POSITION": HOME_POSITION_RATE_HZ if slow > 0 else 0.0}
    rates = {name: hz for name, hz in rates.items() if hz > 0}
    if cfg.stop_unread_streams:  # 0 Hz: SET_MESSAGE_INTERVAL -1, the stream stops
        rates.update(dict.fromkeys(UNREAD_STREAMS, 0.0))
    return rates


def interval_params(name: str, hz: float) -> tuple[float, float]:
    """MAV_CMD_SET_MESSAGE_INTERVAL's param1 and param2 for ``name`` at ``hz`` (0: stop it), as
    sent (the wire then rounds them to float32); ValueError for an unknown message or a bad rate."""
    msg_id = getattr(ardupilotmega, f"MAVLINK_MSG_ID_{name}", None)
    if msg_id is None or not math.isfinite(hz) or hz < 0:
        raise ValueError(f"cannot request {name} at {hz} Hz: unknown message or bad rate")
    return float(msg_id), 1e6 / hz if hz > 0 else -1.0


def _is_complaint(msg: Any) -> bool:
    """A STATUSTEXT of severity WARNING or worse (ArduPilot's "PreArm: ..." are CRITICAL)."""
    return msg.get_type() == "STATUSTEXT" and msg.severity <= mavlink.MAV_SEVERITY_WARNING


def message_id(message_name: str) -> int:
    """The MAVLink id of a message name of the link's dialect (common.xml and ArduPilot's
    ardupilotmega.xml, which includes it); ValueError with the fix otherwise."""
    msg_id = getattr(ardupilotmega, f"MAVLINK_MSG_ID_{message_name}", None)
    if not isinstance(msg_id, int):
        raise ValueError(
            f"unknown MAVLink message {message_name!r}; use its name from common.xml, "
            "e.g. VIDEO_STREAM_INFORMATION"
        )
    return msg_id


def message_fields(msg: Any) -> dict[str, Any]:
    """A received message's fields by MAVLink name (pymavlink decodes char arrays to str)."""
    fields = dict(msg.to_dict())
    fields.pop("mavpackettype", None)
    return fields


def _stamp(snapshot: VehicleSnapshot, echo_time_boot_ms: int | None) -> int:
    """The setpoint's time_boot_ms: the echoed frame, else the newest frame heard."""
    if echo_time_boot_ms is None:
        frame = snapshot.frame_time_boot_ms
        return int(frame if frame is not None else snapshot.time_boot_ms)
    if not 0 <= int(echo_time_boot_ms) <= UINT32_MAX:
        raise ValueError(f"echo_time_boot_ms {echo_time_boot_ms} is not a uint32 ms stamp")
    return int(echo_time_boot_ms)
