"""Folding received MAVLink messages into a new immutable :class:`VehicleSnapshot`.

Pure functions, so the I/O thread only has to swap one reference and the rules can be tested
without sockets.
"""

from __future__ import annotations

import math
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

import companion.link.px4_modes as px4_modes
from companion.link.truth import POSE_FROM
from companion.msg.snapshot import LANDED_STATES, VehicleSnapshot

MAV_MODE_FLAG_SAFETY_ARMED = mavlink.MAV_MODE_FLAG_SAFETY_ARMED
NOT_A_VEHICLE = {
    mavlink.MAV_TYPE_GCS,
    mavlink.MAV_TYPE_ONBOARD_CONTROLLER,
    mavlink.MAV_TYPE_GIMBAL,
    mavlink.MAV_TYPE_ADSB,
    mavlink.MAV_TYPE_CAMERA,
}


class InvalidTelemetry(ValueError):
    """A telemetry message carried a non-finite value."""


def is_vehicle_heartbeat(msg: Any) -> bool:
    """An autopilot's HEARTBEAT (not a ground station's, camera's or companion's)."""
    return (
        msg.get_type() == "HEARTBEAT"
        and msg.autopilot != mavlink.MAV_AUTOPILOT_INVALID
        and msg.type not in NOT_A_VEHICLE
    )


def autopilot_name(autopilot: int) -> str:
    entry = mavlink.enums["MAV_AUTOPILOT"].get(autopilot)
    return entry.name.removeprefix("MAV_AUTOPILOT_") if entry else f"UNKNOWN({autopilot})"


def mode_name(msg: Any) -> str:
    """PX4 mode name of a heartbeat; other autopilots through pymavlink's tables."""
    if msg.autopilot == mavlink.MAV_AUTOPILOT_PX4:
        return px4_modes.decode(msg.custom_mode)
    from pymavlink import mavutil

    return str(mavutil.mode_string_v10(msg))


def _finite(*values: float) -> tuple[float, float, float]:
    if not all(math.isfinite(v) for v in values):
        raise InvalidTelemetry(values)
    return tuple(float(v) for v in values)  # type: ignore[return-value]


def initial_snapshot(msg: Any, now_s: float) -> VehicleSnapshot:
    """The first snapshot, from the vehicle's first heartbeat."""
    zero = (0.0, 0.0, 0.0)
    return VehicleSnapshot(
        received_s=now_s,
        time_boot_ms=0,
        frame_time_boot_ms=None,
        system_id=msg.get_srcSystem(),
        autopilot=autopilot_name(msg.autopilot),
        armed=bool(msg.base_mode & MAV_MODE_FLAG_SAFETY_ARMED),
        mode=mode_name(msg),
        landed_state="UNDEFINED",
        position_ned_m=zero,
        velocity_ned_m_s=zero,
        attitude_rad=zero,
        rates_frd_rad_s=zero,
        heartbeat_s=now_s,
    )


# Each handler gives the fields a message changes; apply_message makes one new snapshot of them.
def _heartbeat(msg: Any, now_s: float) -> dict[str, Any]:
    return {"armed": bool(msg.base_mode & MAV_MODE_FLAG_SAFETY_ARMED), "mode": mode_name(msg), "heartbeat_s": now_s}


def _local_position(msg: Any, now_s: float) -> dict[str, Any]:
    stamp = int(msg.time_boot_ms)
    return {"time_boot_ms": stamp, "position_time_boot_ms": stamp, "position_ned_m": _finite(msg.x, msg.y, msg.z),
            "velocity_ned_m_s": _finite(msg.vx, msg.vy, msg.vz), "position_valid": True}


def _attitude(msg: Any, now_s: float) -> dict[str, Any]:
    stamp = int(msg.time_boot_ms)
    return {"time_boot_ms": stamp, "attitude_time_boot_ms": stamp, "attitude_rad": _finite(msg.roll, msg.pitch, msg.yaw),
            "rates_frd_rad_s": _finite(msg.rollspeed, msg.pitchspeed, msg.yawspeed), "attitude_valid": True}


def _extended_sys_state(msg: Any, now_s: float) -> dict[str, Any]:
    state = int(msg.landed_state)
    return {"landed_state": LANDED_STATES[state] if state < len(LANDED_STATES) else "UNDEFINED"}


def _home_position(msg: Any, now_s: float) -> dict[str, Any]:
    return {"home_ned_m": _finite(msg.x, msg.y, msg.z)}


UINT16_WRAP_FROM = 65536 - 100  # readings of -1 to -100 cm as PX4 SIH's uint16 field carries them


def _distance_sensor(msg: Any, now_s: float) -> dict[str, Any]:
    """A downward rangefinder only; a reading outside [min, max] is no reading, except PX4 SIH's
    wrapped negative distances (65535 = -1 cm) while its vehicle presses into the ground: those
    are the surface itself."""
    if int(msg.orientation) != mavlink.MAV_SENSOR_ROTATION_PITCH_270:
        return {}
    cm = int(msg.current_distance)
    if cm >= UINT16_WRAP_FROM:  # a small negative distance, wrapped: at (or pressed into) the surface
        return {"ground_distance_m": 0.0, "ground_distance_s": now_s}
    valid = int(msg.min_distance) <= cm <= int(msg.max_distance)
    return {"ground_distance_m": cm / 100.0 if valid else None, "ground_distance_s": now_s}


def _lat_lon(lat_e7: int, lon_e7: int) -> tuple[float, float] | None:
    return None if lat_e7 == 0 and lon_e7 == 0 else (lat_e7 / 1e7, lon_e7 / 1e7)


def _hil_state(msg: Any, now_s: float) -> dict[str, Any]:
    return {"truth_lat_lon_deg": _lat_lon(int(msg.lat), int(msg.lon))}


def _simstate(msg: Any, now_s: float) -> dict[str, Any]:
    return {"truth_lat_lon_deg": _lat_lon(int(msg.lat), int(msg.lng))}


def _sim_state(msg: Any, now_s: float) -> dict[str, Any]:
    return {"truth_lat_lon_deg": _lat_lon(int(msg.lat_int), int(msg.lon_int))}


def _global_origin(msg: Any, now_s: float) -> dict[str, Any]:
    origin = _lat_lon(int(msg.latitude), int(msg.longitude))
    if origin is None:
        return {"origin_lat_lon_deg": None}
    return {"origin_lat_lon_deg": origin, "origin_alt_m": int(msg.altitude) / 1000.0}


def _true_pose(kind: str, msg: Any, snapshot: VehicleSnapshot, now_s: float) -> dict[str, Any]:
    """The simulator's true pose in the local frame (companion/link/truth.py); a message before
    the origin is known leaves the last pose as it was."""
    try:
        pose = POSE_FROM[kind](msg, snapshot, now_s)
    except (TypeError, ValueError) as exc:  # non-finite truth
        raise InvalidTelemetry(f"{kind}: {exc}") from None
    return {} if pose is None else {"true_pose": pose}


def _system_time(msg: Any, now_s: float) -> dict[str, Any]:
    return {"time_boot_ms": int(msg.time_boot_ms)}


def with_changes(snapshot: VehicleSnapshot, changes: dict[str, Any]) -> VehicleSnapshot:
    """``dataclasses.replace`` without its per-field getattr and ``__init__``: a snapshot has no
    validation to rerun, and this runs for every message (five per lockstep frame)."""
    new = object.__new__(VehicleSnapshot)
    new.__dict__.update(snapshot.__dict__)
    new.__dict__.update(changes)
    return new


HANDLERS = {
    "HEARTBEAT": _heartbeat,
    "LOCAL_POSITION_NED": _local_position,
    "ATTITUDE": _attitude,
    "EXTENDED_SYS_STATE": _extended_sys_state,
    "SYSTEM_TIME": _system_time,
    "HOME_POSITION": _home_position,
    "DISTANCE_SENSOR": _distance_sensor,
    "HIL_STATE_QUATERNION": _hil_state,
    "SIMSTATE": _simstate,
    "SIM_STATE": _sim_state,
    "GPS_GLOBAL_ORIGIN": _global_origin,
}


def apply_message(
    snapshot: VehicleSnapshot, msg: Any, now_s: float, frame_marker: str
) -> VehicleSnapshot:
    """The snapshot after ``msg``; raises InvalidTelemetry for non-finite values.

    ``frame_marker`` names the message type whose arrival marks a new frame (SYSTEM_TIME in
    lockstep; a telemetry message such as LOCAL_POSITION_NED on a real vehicle).
    """
    kind = msg.get_type()
    if kind == "HEARTBEAT" and not is_vehicle_heartbeat(msg):
        return snapshot
    handler = HANDLERS.get(kind)
    changes = handler(msg, now_s) if handler else {}
    if kind in POSE_FROM:
        changes.update(_true_pose(kind, msg, snapshot, now_s))
    if kind == frame_marker and hasattr(msg, "time_boot_ms"):
        changes["frame_time_boot_ms"] = int(msg.time_boot_ms)
    changes["received_s"] = now_s
    return with_changes(snapshot, changes)
