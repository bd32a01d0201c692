"""Turning SET_POSITION_TARGET_LOCAL_NED into a controller setpoint, honouring type_mask.

A set bit in ``type_mask`` means "ignore this field" (MAVLink's POSITION_TARGET_TYPEMASK).
Body frames are rotated by the vehicle's heading at reception, as PX4 does. A value that is
used but not finite makes the whole message invalid: it is refused, never flown.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from sitl.control import Setpoint

IGNORE_X, IGNORE_Y, IGNORE_Z = 1, 2, 4
IGNORE_VX, IGNORE_VY, IGNORE_VZ = 8, 16, 32
IGNORE_AX, IGNORE_AY, IGNORE_AZ = 64, 128, 256
FORCE = 512
IGNORE_YAW, IGNORE_YAW_RATE = 1024, 2048

FRAME_LOCAL_NED = 1
FRAME_LOCAL_OFFSET_NED = 7
FRAME_BODY_NED = 8
FRAME_BODY_OFFSET_NED = 9
FRAME_BODY_FRD = 12
BODY_FRAMES = (FRAME_BODY_NED, FRAME_BODY_OFFSET_NED, FRAME_BODY_FRD)
SUPPORTED_FRAMES = (FRAME_LOCAL_NED, FRAME_LOCAL_OFFSET_NED, *BODY_FRAMES)
ABSOLUTE_FRAMES = (FRAME_LOCAL_NED, FRAME_BODY_NED, FRAME_BODY_FRD)  # positions from the origin
NAN = math.nan


@dataclass(frozen=True)
class TargetFields:
    """The fields of SET_POSITION_TARGET_LOCAL_NED that matter to the autopilot."""

    frame: int
    type_mask: int
    x: float
    y: float
    z: float
    vx: float
    vy: float
    vz: float
    yaw: float
    yaw_rate: float


class SetpointRejected(ValueError):
    """The message cannot be flown; the reason goes to STATUSTEXT."""


def _rotate(forward: float, right: float, yaw_rad: float) -> tuple[float, float]:
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    return c * forward - s * right, s * forward + c * right


def _rotate_pair(forward: float, right: float, yaw_rad: float) -> tuple[float, float]:
    """Rotate a body pair to NED; one ignored component counts as 0, both ignored stay NaN."""
    if math.isnan(forward) and math.isnan(right):
        return NAN, NAN
    return _rotate(0.0 if math.isnan(forward) else forward, 0.0 if math.isnan(right) else right, yaw_rad)


def _pick(values: tuple[float, float, float], masks: tuple[int, int, int], type_mask: int) -> list[float]:
    out = []
    for v, bit in zip(values, masks):
        if type_mask & bit:
            out.append(NAN)
        elif not math.isfinite(v):
            raise SetpointRejected(f"non-finite value {v} in a used field")
        else:
            out.append(float(v))
    return out


def from_reported_frame(f: TargetFields, height_offset_m: float) -> TargetFields:
    """``f`` with a position from the origin moved from the reported local frame (the
    estimator's, ``height_offset_m`` below the true one) into the true one; relative positions,
    velocities and offset 0 are left alone (no arithmetic: bit for bit as before)."""
    if height_offset_m == 0.0 or f.frame not in ABSOLUTE_FRAMES or f.type_mask & IGNORE_Z:
        return f
    return replace(f, z=f.z + height_offset_m)


def to_setpoint(
    f: TargetFields, position_ned_m: tuple[float, float, float], yaw_rad: float, max_speed_m_s: float
) -> Setpoint:
    """The controller setpoint for ``f`` given the vehicle's pose at reception."""
    if f.frame not in SUPPORTED_FRAMES:
        raise SetpointRejected(f"coordinate frame {f.frame} not supported")
    if f.type_mask & FORCE:
        raise SetpointRejected("force setpoints are not supported")
    pos = _pick((f.x, f.y, f.z), (IGNORE_X, IGNORE_Y, IGNORE_Z), f.type_mask)
    vel = _pick((f.vx, f.vy, f.vz), (IGNORE_VX, IGNORE_VY, IGNORE_VZ), f.type_mask)
    yaw = _pick((f.yaw, 0.0, 0.0), (IGNORE_YAW, 0, 0), f.type_mask)[0]
    yaw_rate = _pick((f.yaw_rate, 0.0, 0.0), (IGNORE_YAW_RATE, 0, 0), f.type_mask)[0]
    if all(math.isnan(v) for v in (*pos, *vel, yaw, yaw_rate)):
        raise SetpointRejected("type_mask ignores every field")
    if f.frame in BODY_FRAMES:
        vel[0], vel[1] = _rotate_pair(vel[0], vel[1], yaw_rad)
        pos[0], pos[1] = _rotate_pair(pos[0], pos[1], yaw_rad)
        if not math.isnan(yaw):
            yaw += yaw_rad
    if f.frame in (FRAME_LOCAL_OFFSET_NED, FRAME_BODY_OFFSET_NED):
        pos = [p + c if not math.isnan(p) else NAN for p, c in zip(pos, position_ned_m)]
    vel = [max(-max_speed_m_s, min(max_speed_m_s, v)) if not math.isnan(v) else NAN for v in vel]
    return Setpoint(
        position_ned_m=(pos[0], pos[1], pos[2]),
        velocity_ned_m_s=(vel[0], vel[1], vel[2]),
        yaw_rad=yaw,
        yaw_rate_rad_s=yaw_rate,
    )
