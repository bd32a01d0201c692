"""The scripted autopilot behind :class:`~companion.testing.fake_vehicle.FakeVehicle`.

No sockets here: it turns received MAVLink messages into state changes and replies, and its
state into telemetry, so the behaviour is plain to read and to script. It is a caricature of
PX4 (instant mode changes, first-order kinematics), just enough for link and session tests.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

import companion.link.px4_modes as px4_modes

BODY_VELOCITY_MASK = 0x5C7
LANDED = {"UNDEFINED": 0, "ON_GROUND": 1, "IN_AIR": 2, "TAKEOFF": 3, "LANDING": 4}
ALL_SENSORS_HEALTHY = 0x3FFFFFFF


def result_code(result: str | int) -> int:
    """A MAV_RESULT value from its name ("DENIED", "MAV_RESULT_DENIED") or number."""
    if isinstance(result, int):
        return result
    name = result.upper()
    name = name if name.startswith("MAV_RESULT_") else f"MAV_RESULT_{name}"
    return int(getattr(mavlink, name))


@dataclass
class AutopilotState:
    """Mutable state of the fake autopilot (owned by its thread, read under its lock)."""

    armed: bool = False
    mode: str = "AUTO.LOITER"
    landed_state: str = "ON_GROUND"
    position_ned_m: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    velocity_ned_m_s: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    yaw_rad: float = 0.0
    yaw_rate_rad_s: float = 0.0
    body_velocity: tuple[float, float, float, float] | None = None  # fwd, right, down, yaw rate
    position_target: tuple[float, float, float, float] | None = None  # n, e, d, yaw
    params: dict[str, float] = field(default_factory=lambda: {"MIS_TAKEOFF_ALT": 2.5})


class FakeAutopilot:
    """Command handling, setpoint following and telemetry of the fake vehicle."""

    def __init__(self, mav: Any, arm_result: str | int = "ACCEPTED") -> None:
        self.mav = mav  # a pymavlink MAVLink encoder with the vehicle's identity
        self.state = AutopilotState()
        self.arm_result = result_code(arm_result)
        self.ack_commands = True
        self.drop_param_echoes = 0  # this many PARAM_SETs are applied but not echoed (a lost reply)

    # ----------------------------------------------------------------- commands
    def handle(self, msg: Any) -> list[Any]:
        """Replies to one received message."""
        kind = msg.get_type()
        if kind in ("COMMAND_LONG", "COMMAND_INT"):
            return self._command(msg)
        if kind == "SET_POSITION_TARGET_LOCAL_NED":
            self._setpoint(msg)
        elif kind == "PARAM_SET":
            self.state.params[msg.param_id] = float(msg.param_value)
            if self.drop_param_echoes > 0:
                self.drop_param_echoes -= 1
                return []
            return [self._param_value(msg.param_id)]
        elif kind == "PARAM_REQUEST_READ" and msg.param_id in self.state.params:
            return [self._param_value(msg.param_id)]
        return []

    def _command(self, msg: Any) -> list[Any]:
        params = [msg.param1, msg.param2, msg.param3, msg.param4]
        params += (
            [msg.param5, msg.param6, msg.param7]
            if hasattr(msg, "param5")
            else [msg.x, msg.y, msg.z]
        )
        result, extra = self._execute(int(msg.command), params)
        if not self.ack_commands:
            return []
        ack = self.mav.command_ack_encode(
            msg.command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()
        )
        return [ack, *extra]

    def _execute(self, command: int, p: list[float]) -> tuple[int, list[Any]]:
        handlers = {
            mavlink.MAV_CMD_COMPONENT_ARM_DISARM: self._arm_disarm,
            mavlink.MAV_CMD_DO_SET_MODE: self._set_mode,
            mavlink.MAV_CMD_NAV_TAKEOFF: self._takeoff,
            mavlink.MAV_CMD_NAV_LAND: self._land,
            mavlink.MAV_CMD_SET_MESSAGE_INTERVAL: lambda p: (mavlink.MAV_RESULT_ACCEPTED, []),
            mavlink.MAV_CMD_REQUEST_MESSAGE: self._request_message,
            mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES: lambda p: (
                mavlink.MAV_RESULT_ACCEPTED,
                [self.autopilot_version()],
            ),
        }
        handler = handlers.get(command)
        return handler(p) if handler else (mavlink.MAV_RESULT_UNSUPPORTED, [])

    def _arm_disarm(self, p: list[float]) -> tuple[int, list[Any]]:
        if p[0] >= 0.5:
            if self.arm_result != mavlink.MAV_RESULT_ACCEPTED:
                return self.arm_result, []
            self.state.armed = True
        else:
            self.state.armed = False
            self.state.landed_state = "ON_GROUND" if self.state.position_ned_m[2] >= 0 else "IN_AIR"
        return mavlink.MAV_RESULT_ACCEPTED, []

    def _set_mode(self, p: list[float]) -> tuple[int, list[Any]]:
        name = px4_modes.decode(int(p[1]) << 16 | int(p[2]) << 24)
        if name.startswith("UNKNOWN"):
            return mavlink.MAV_RESULT_UNSUPPORTED, []
        self.state.mode = name
        if name in ("AUTO.LAND", "AUTO.PRECLAND"):  # both descend here; PRECLAND towards nothing
            self.state.landed_state = (
                "LANDING" if self.state.landed_state == "IN_AIR" else self.state.landed_state
            )
        return mavlink.MAV_RESULT_ACCEPTED, []

    def _takeoff(self, p: list[float]) -> tuple[int, list[Any]]:
        if not self.state.armed:
            return mavlink.MAV_RESULT_DENIED, []
        alt_m = self.state.params.get("MIS_TAKEOFF_ALT", 2.5)
        self.state.mode = "AUTO.TAKEOFF"
        self.state.landed_state = "TAKEOFF"
        north, east, _ = self.state.position_ned_m
        self.state.position_target = (north, east, -alt_m, self.state.yaw_rad)
        return mavlink.MAV_RESULT_ACCEPTED, []

    def _land(self, p: list[float]) -> tuple[int, list[Any]]:
        self.state.mode = "AUTO.LAND"
        if self.state.landed_state != "ON_GROUND":
            self.state.landed_state = "LANDING"
        return mavlink.MAV_RESULT_ACCEPTED, []

    def _request_message(self, p: list[float]) -> tuple[int, list[Any]]:
        replies = {
            mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION: self.autopilot_version,
            mavlink.MAVLINK_MSG_ID_HOME_POSITION: self.home_position,
        }
        make = replies.get(int(p[0]))
        if make is None:
            return mavlink.MAV_RESULT_UNSUPPORTED, []
        return mavlink.MAV_RESULT_ACCEPTED, [make()]

    def _setpoint(self, msg: Any) -> None:
        if (
            msg.coordinate_frame == mavlink.MAV_FRAME_BODY_NED
            and msg.type_mask == BODY_VELOCITY_MASK
        ):
            self.state.body_velocity = (msg.vx, msg.vy, msg.vz, msg.yaw_rate)
            self.state.position_target = None
        elif msg.coordinate_frame == mavlink.MAV_FRAME_LOCAL_NED and not msg.type_mask & 0x7:
            self.state.position_target = (msg.x, msg.y, msg.z, msg.yaw)
            self.state.body_velocity = None

    def _param_value(self, name: str) -> Any:
        names = sorted(self.state.params)
        return self.mav.param_value_encode(
            name.encode(),
            self.state.params[name],
            mavlink.MAV_PARAM_TYPE_REAL32,
            len(names),
            names.index(name),
        )

    # ----------------------------------------------------------------- motion
    def advance(self, dt_s: float) -> None:
        """Move for ``dt_s``: follow the active setpoint, descend when landing."""
        s = self.state
        velocity = [0.0, 0.0, 0.0]
        s.yaw_rate_rad_s = 0.0
        if s.mode == "OFFBOARD" and s.body_velocity is not None:
            fwd, right, down, s.yaw_rate_rad_s = s.body_velocity
            c, si = math.cos(s.yaw_rad), math.sin(s.yaw_rad)
            velocity = [c * fwd - si * right, si * fwd + c * right, down]
        elif s.position_target is not None and s.mode in ("OFFBOARD", "AUTO.TAKEOFF"):
            velocity = _towards(s.position_ned_m, s.position_target[:3], 2.0)
        elif s.landed_state == "LANDING":
            velocity = [0.0, 0.0, 1.0]
        if not s.armed or (s.landed_state == "ON_GROUND" and velocity[2] >= 0):
            velocity = [0.0, 0.0, 0.0]
            s.yaw_rate_rad_s = 0.0
        s.velocity_ned_m_s = velocity
        s.position_ned_m = [p + v * dt_s for p, v in zip(s.position_ned_m, velocity, strict=True)]
        s.yaw_rad = math.remainder(s.yaw_rad + s.yaw_rate_rad_s * dt_s, 2 * math.pi)
        self._update_landed()

    def _update_landed(self) -> None:
        s = self.state
        if s.position_ned_m[2] >= 0.0:
            s.position_ned_m[2] = 0.0
            if s.landed_state in ("LANDING", "IN_AIR"):
                s.landed_state = "ON_GROUND"
        elif s.armed and s.landed_state == "ON_GROUND":
            s.landed_state = "IN_AIR"
        if (
            s.mode == "AUTO.TAKEOFF"
            and s.position_target
            and abs(s.position_ned_m[2] - s.position_target[2]) < 0.05
        ):
            s.mode, s.landed_state, s.position_target = "AUTO.LOITER", "IN_AIR", None

    # ----------------------------------------------------------------- telemetry
    def heartbeat(self) -> Any:
        base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED if self.state.armed else 0
        return self.mav.heartbeat_encode(
            mavlink.MAV_TYPE_QUADROTOR,
            mavlink.MAV_AUTOPILOT_PX4,
            base,
            px4_modes.custom_mode(self.state.mode),
            mavlink.MAV_STATE_ACTIVE,
        )

    def telemetry(self, time_boot_ms: int) -> list[Any]:
        s = self.state
        n, e, d = s.position_ned_m
        vn, ve, vd = s.velocity_ned_m_s
        return [
            self.mav.attitude_encode(time_boot_ms, 0.0, 0.0, s.yaw_rad, 0.0, 0.0, s.yaw_rate_rad_s),
            self.mav.local_position_ned_encode(time_boot_ms, n, e, d, vn, ve, vd),
            self.mav.global_position_int_encode(
                time_boot_ms,
                int((47.3977 + n / 111_320) * 1e7),
                int((8.5456 + e / 75_500) * 1e7),
                int((488.0 - d) * 1000),
                int(-d * 1000),
                int(vn * 100),
                int(ve * 100),
                int(vd * 100),
                int(math.degrees(s.yaw_rad) % 360 * 100),
            ),
            self.mav.extended_sys_state_encode(
                mavlink.MAV_VTOL_STATE_UNDEFINED, LANDED[s.landed_state]
            ),
        ]

    def slow_telemetry(self) -> list[Any]:
        """Once a second: what MAVSDK wants before it reports a vehicle as ready."""
        healthy = ALL_SENSORS_HEALTHY
        return [
            self.mav.sys_status_encode(
                healthy, healthy, healthy, 0, 16000, -1, 90, 0, 0, 0, 0, 0, 0
            ),
            self.home_position(),
        ]

    def home_position(self) -> Any:
        return self.mav.home_position_encode(
            473977000, 85456000, 488000, 0.0, 0.0, 0.0, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0
        )

    def autopilot_version(self) -> Any:
        caps = (
            mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
            | mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
            | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
        )
        return self.mav.autopilot_version_encode(
            caps, 0x010F0000, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, 1
        )


def _towards(position: list[float], target: tuple[float, ...], speed_m_s: float) -> list[float]:
    delta = [t - p for p, t in zip(position, target, strict=True)]
    dist = math.sqrt(sum(x * x for x in delta))
    if dist < 1e-6:
        return [0.0, 0.0, 0.0]
    scale = min(speed_m_s, dist * 5.0) / dist
    return [x * scale for x in delta]
