"""SET_POSITION_TARGET_LOCAL_NED -> setpoint: type_mask, frames, refusals."""

import math

import pytest

from sitl.offboard import (
    FRAME_BODY_FRD,
    FRAME_BODY_NED,
    FRAME_BODY_OFFSET_NED,
    FRAME_LOCAL_NED,
    FRAME_LOCAL_OFFSET_NED,
    SetpointRejected,
    TargetFields,
    to_setpoint,
)

VEL_YAWRATE = 0x5C7  # velocity + yaw rate used
VEL_NED = 0x9C7  # velocity + yaw used
POS_ONLY = 0xDF8
NAN = math.nan


def fields(frame=FRAME_LOCAL_NED, mask=VEL_YAWRATE, x=0.0, y=0.0, z=0.0, vx=0.0, vy=0.0, vz=0.0, yaw=0.0, yaw_rate=0.0):
    return TargetFields(frame, mask, x, y, z, vx, vy, vz, yaw, yaw_rate)


def test_velocity_and_yaw_rate_mask_ignores_position_and_yaw() -> None:
    sp = to_setpoint(fields(vx=1.0, vy=-0.5, vz=0.2, x=99, yaw=3, yaw_rate=0.3), (0, 0, -5), 0.0, 5.0)
    assert all(math.isnan(p) for p in sp.position_ned_m)
    assert sp.velocity_ned_m_s == (1.0, -0.5, 0.2)
    assert math.isnan(sp.yaw_rad) and sp.yaw_rate_rad_s == 0.3


@pytest.mark.parametrize("frame", [FRAME_BODY_NED, FRAME_BODY_FRD, FRAME_BODY_OFFSET_NED])
def test_body_velocity_is_rotated_by_heading(frame: int) -> None:
    sp = to_setpoint(fields(frame=frame, vx=1.0), (0, 0, -5), math.pi / 2, 5.0)
    vn, ve, vd = sp.velocity_ned_m_s
    assert vn == pytest.approx(0.0, abs=1e-9) and ve == pytest.approx(1.0) and vd == 0.0


def test_position_mask_and_offsets() -> None:
    sp = to_setpoint(fields(mask=POS_ONLY, x=1, y=2, z=-3), (10, 20, -5), 0.0, 5.0)
    assert sp.position_ned_m == (1, 2, -3)
    off = to_setpoint(fields(frame=FRAME_LOCAL_OFFSET_NED, mask=POS_ONLY, x=1, y=2, z=-3), (10, 20, -5), 0.0, 5.0)
    assert off.position_ned_m == (11, 22, -8)


def test_velocity_is_clamped_to_the_speed_limit() -> None:
    sp = to_setpoint(fields(vx=50.0, vy=-50.0), (0, 0, -5), 0.0, 5.0)
    assert sp.velocity_ned_m_s[:2] == (5.0, -5.0)


def test_nan_in_a_used_field_is_refused_but_ignored_nan_is_fine() -> None:
    with pytest.raises(SetpointRejected, match="non-finite"):
        to_setpoint(fields(vx=NAN), (0, 0, -5), 0.0, 5.0)
    sp = to_setpoint(fields(x=NAN, yaw=NAN, vx=1.0), (0, 0, -5), 0.0, 5.0)
    assert sp.velocity_ned_m_s[0] == 1.0


def test_unsupported_frame_force_and_all_ignored_are_refused() -> None:
    with pytest.raises(SetpointRejected, match="frame"):
        to_setpoint(fields(frame=3), (0, 0, 0), 0.0, 5.0)
    with pytest.raises(SetpointRejected, match="force"):
        to_setpoint(fields(mask=VEL_YAWRATE | 512), (0, 0, 0), 0.0, 5.0)
    with pytest.raises(SetpointRejected, match="ignores every"):
        to_setpoint(fields(mask=0xDFF), (0, 0, 0), 0.0, 5.0)
