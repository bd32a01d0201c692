"""What the vehicle tells the world: telemetry messages composed from its state, on schedules.

Rates are in simulation time and can be changed with SET_MESSAGE_INTERVAL, as on PX4. In
lockstep a stream is sent at most once per frame; in real time at most once per FDM step.
"""

from __future__ import annotations

import math
from collections.abc import Callable

from pymavlink.dialects.v20 import common as mavlink

from sitl.vehicle import SimVehicle

M = mavlink
UNIX_EPOCH_AT_BOOT_US = 1_767_225_600_000_000  # 2026-01-01T00:00:00Z: deterministic wall stamps
EARTH_RADIUS_M = 6_378_137.0

PRESENT = (
    M.MAV_SYS_STATUS_SENSOR_3D_GYRO
    | M.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    | M.MAV_SYS_STATUS_SENSOR_3D_MAG
    | M.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
    | M.MAV_SYS_STATUS_SENSOR_GPS
    | M.MAV_SYS_STATUS_SENSOR_ANGULAR_RATE_CONTROL
    | M.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION
    | M.MAV_SYS_STATUS_SENSOR_YAW_POSITION
    | M.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL
    | M.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
    | M.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
    | M.MAV_SYS_STATUS_SENSOR_BATTERY
    | M.MAV_SYS_STATUS_GEOFENCE
    | M.MAV_SYS_STATUS_AHRS
    | M.MAV_SYS_STATUS_PREARM_CHECK
)

DEFAULT_RATES_HZ: dict[int, float] = {
    M.MAVLINK_MSG_ID_HEARTBEAT: 1.0,
    M.MAVLINK_MSG_ID_SYS_STATUS: 1.0,
    M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 5.0,
    M.MAVLINK_MSG_ID_ATTITUDE: 50.0,
    M.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: 50.0,
    M.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 30.0,
    M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 10.0,
    M.MAVLINK_MSG_ID_GPS_RAW_INT: 5.0,
    M.MAVLINK_MSG_ID_HOME_POSITION: 0.5,
    M.MAVLINK_MSG_ID_BATTERY_STATUS: 1.0,
    M.MAVLINK_MSG_ID_VFR_HUD: 4.0,
}


def euler_to_quaternion(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """ZYX Euler angles to a (w, x, y, z) quaternion, as MAVLink's ATTITUDE_QUATERNION wants."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


def ned_to_geodetic(v: SimVehicle, n: float, e: float, d: float) -> tuple[int, int, int]:
    """Local NED to (lat 1e7 deg, lon 1e7 deg, alt AMSL mm), flat earth around home."""
    lat0, lon0 = v.dynamics.home_lat_deg, v.dynamics.home_lon_deg
    lat = lat0 + math.degrees(n / EARTH_RADIUS_M)
    lon = lon0 + math.degrees(e / (EARTH_RADIUS_M * math.cos(math.radians(lat0))))
    alt = v.dynamics.home_alt_m - d
    return int(round(lat * 1e7)), int(round(lon * 1e7)), int(round(alt * 1000))


def heartbeat(v: SimVehicle) -> mavlink.MAVLink_message:
    base = M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | M.MAV_MODE_FLAG_STABILIZE_ENABLED
    if v.mode.name in ("POSCTL", "ALTCTL", "MANUAL"):
        base |= M.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED
    if v.mode.name.startswith("AUTO") or v.mode.name == "OFFBOARD":
        base |= M.MAV_MODE_FLAG_AUTO_ENABLED | M.MAV_MODE_FLAG_GUIDED_ENABLED
    if v.armed:
        base |= M.MAV_MODE_FLAG_SAFETY_ARMED
    status = M.MAV_STATE_ACTIVE if v.armed else M.MAV_STATE_STANDBY
    autopilot, custom_mode = v.heartbeat_mode()
    return M.MAVLink_heartbeat_message(M.MAV_TYPE_QUADROTOR, autopilot, base, custom_mode, status, 3)


def sys_status(v: SimVehicle) -> mavlink.MAVLink_message:
    return M.MAVLink_sys_status_message(PRESENT, PRESENT, PRESENT, 250, 16200, 1000, 90, 0, 0, 0, 0, 0, 0)


def extended_sys_state(v: SimVehicle) -> mavlink.MAVLink_message:
    return M.MAVLink_extended_sys_state_message(M.MAV_VTOL_STATE_MC, v.landed_state)


def attitude_fields(v: SimVehicle) -> tuple[int, float, float, float, float, float, float]:
    """ATTITUDE's fields in message order (time_boot_ms, roll, pitch, yaw, rollspeed, pitchspeed,
    yawspeed), before the wire rounds them to float32: also read without a message
    (companion/rl/direct_sitl.py)."""
    (r, p, y), rates = v.reported_attitude()
    return (v.time_boot_ms, r, p, y, *rates)


def attitude(v: SimVehicle) -> mavlink.MAVLink_message:
    return M.MAVLink_attitude_message(*attitude_fields(v))


def attitude_quaternion(v: SimVehicle) -> mavlink.MAVLink_message:
    att, rates = v.reported_attitude()
    q = euler_to_quaternion(*att)
    return M.MAVLink_attitude_quaternion_message(v.time_boot_ms, *q, *rates, [0, 0, 0, 0])


def local_position_fields(v: SimVehicle) -> tuple[int, float, float, float, float, float, float]:
    """LOCAL_POSITION_NED's fields in message order (time_boot_ms, x, y, z, vx, vy, vz), before the
    wire rounds them to float32. In the estimator's frame: z is ``height_offset_m`` less than the
    truth (x - 0.0 is exact), and north and east are the estimate's (sitl/estimate_error.py)."""
    s = v.estimate
    n, e, d = s.position_ned_m
    return (v.time_boot_ms, n, e, d - v.height_offset_m, *s.velocity_ned_m_s)


def local_position_ned(v: SimVehicle) -> mavlink.MAVLink_message:
    return M.MAVLink_local_position_ned_message(*local_position_fields(v))


def global_position_int(v: SimVehicle) -> mavlink.MAVLink_message:
    s = v.estimate
    n, e, d = s.position_ned_m
    lat, lon, alt = ned_to_geodetic(v, n, e, d)
    vn, ve, vd = (int(round(c * 100)) for c in s.velocity_ned_m_s)
    hdg = int(round(math.degrees(s.attitude_rad[2]) % 360 * 100))
    rel_mm = int(round(-(d - v.home_ned_m[2]) * 1000))
    return M.MAVLink_global_position_int_message(v.time_boot_ms, lat, lon, alt, rel_mm, vn, ve, vd, hdg)


def gps_raw_int(v: SimVehicle) -> mavlink.MAVLink_message:
    s = v.state
    lat, lon, alt = ned_to_geodetic(v, *s.position_ned_m)
    vn, ve, _ = s.velocity_ned_m_s
    vel = int(round(math.hypot(vn, ve) * 100))
    cog = int(round(math.degrees(math.atan2(ve, vn)) % 360 * 100)) if vel > 0 else 65535
    return M.MAVLink_gps_raw_int_message(v.time_usec, M.GPS_FIX_TYPE_3D_FIX, lat, lon, alt, 80, 120, vel, cog, 14)


def home_local(v: SimVehicle) -> tuple[float, float, float]:
    """HOME_POSITION's x, y, z: home in the reported local frame (before the wire's float32)."""
    n, e, d = v.home_ned_m
    return n, e, d - v.height_offset_m


def home_position(v: SimVehicle) -> mavlink.MAVLink_message:
    """Home's true latitude, longitude and AMSL altitude; its x, y, z in the reported local frame."""
    n, e, d = v.home_ned_m
    lat, lon, alt = ned_to_geodetic(v, n, e, d)
    return M.MAVLink_home_position_message(lat, lon, alt, *home_local(v), [1, 0, 0, 0], 0, 0, 0, v.time_usec)


def battery_status(v: SimVehicle) -> mavlink.MAVLink_message:
    cells = [4050, 4050, 4050, 4050] + [65535] * 6
    return M.MAVLink_battery_status_message(0, M.MAV_BATTERY_FUNCTION_ALL, M.MAV_BATTERY_TYPE_LIPO, 2500, cells, 1000, -1, -1, 90)


def vfr_hud(v: SimVehicle) -> mavlink.MAVLink_message:
    s = v.estimate
    vn, ve, vd = s.velocity_ned_m_s
    gs = math.hypot(vn, ve)
    hdg = int(math.degrees(s.attitude_rad[2]) % 360)
    return M.MAVLink_vfr_hud_message(gs, gs, hdg, 50 if v.armed else 0, v.dynamics.home_alt_m - s.position_ned_m[2], -vd)


def system_time(v: SimVehicle) -> mavlink.MAVLink_message:
    """The lockstep frame marker (see docs/protocols.md)."""
    return M.MAVLink_system_time_message(UNIX_EPOCH_AT_BOOT_US + v.time_usec, v.time_boot_ms)


def autopilot_version(v: SimVehicle) -> mavlink.MAVLink_message:
    caps = (
        M.MAV_PROTOCOL_CAPABILITY_MAVLINK2
        | M.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
        | M.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
        | M.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
    )
    sw = (1 << 24) | (15 << 16) | (0 << 8) | 0xFF  # 1.15.0 release, PX4's version layout
    return M.MAVLink_autopilot_version_message(caps, sw, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, 1)


COMPOSERS: dict[int, Callable[[SimVehicle], mavlink.MAVLink_message]] = {
    M.MAVLINK_MSG_ID_HEARTBEAT: heartbeat,
    M.MAVLINK_MSG_ID_SYS_STATUS: sys_status,
    M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: extended_sys_state,
    M.MAVLINK_MSG_ID_ATTITUDE: attitude,
    M.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: attitude_quaternion,
    M.MAVLINK_MSG_ID_LOCAL_POSITION_NED: local_position_ned,
    M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: global_position_int,
    M.MAVLINK_MSG_ID_GPS_RAW_INT: gps_raw_int,
    M.MAVLINK_MSG_ID_HOME_POSITION: home_position,
    M.MAVLINK_MSG_ID_BATTERY_STATUS: battery_status,
    M.MAVLINK_MSG_ID_VFR_HUD: vfr_hud,
    M.MAVLINK_MSG_ID_SYSTEM_TIME: system_time,
    M.MAVLINK_MSG_ID_AUTOPILOT_VERSION: autopilot_version,
}


class TelemetryScheduler:
    """Which streams are due, by simulation time; intervals settable per message id."""

    def __init__(self, rates_hz: dict[int, float] | None = None) -> None:
        self._default = dict(DEFAULT_RATES_HZ if rates_hz is None else rates_hz)
        self._interval_s = {k: 1.0 / r for k, r in self._default.items() if r > 0}
        self._next_s = dict.fromkeys(self._interval_s, 0.0)

    def set_interval(self, msg_id: int, interval_us: float, now_s: float) -> bool:
        """SET_MESSAGE_INTERVAL semantics: -1 stops, 0 restores the default. False if unknown."""
        if msg_id not in COMPOSERS:
            return False
        if interval_us < 0:
            self._interval_s.pop(msg_id, None)
            self._next_s.pop(msg_id, None)
            return True
        if interval_us == 0:
            rate = self._default.get(msg_id, 0.0)
            if rate <= 0:
                self._interval_s.pop(msg_id, None)
                return True
            self._interval_s[msg_id] = 1.0 / rate
        else:
            self._interval_s[msg_id] = max(interval_us * 1e-6, 1e-3)
        self._next_s[msg_id] = now_s
        return True

    def interval_s(self, msg_id: int) -> float | None:
        return self._interval_s.get(msg_id)

    def restarted(self, rates_hz: dict[int, float] | None, now_s: float) -> TelemetryScheduler:
        """A new scheduler with this one's intervals (the requested ones kept) and its phase
        restarted at ``now_s``, so an episode is independent of the last (an episode reset)."""
        fresh = TelemetryScheduler(rates_hz)
        for msg_id in COMPOSERS:
            interval = self.interval_s(msg_id)
            if interval is None:
                fresh.set_interval(msg_id, -1, now_s)
            elif not math.isclose(interval, fresh.interval_s(msg_id) or -1.0):
                fresh.set_interval(msg_id, interval * 1e6, now_s)
        return fresh

    def due(self, now_s: float) -> list[int]:
        """Message ids due at ``now_s``; each is rescheduled one interval on (no bursts)."""
        out = []
        for msg_id, next_s in self._next_s.items():
            if now_s + 1e-9 >= next_s:
                out.append(msg_id)
                interval = self._interval_s[msg_id]
                self._next_s[msg_id] = max(next_s + interval, now_s + interval * 0.5)
        return out
