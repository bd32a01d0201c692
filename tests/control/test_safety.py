"""Geofence and the setpoint limiter applied last before sending."""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.config import CommandsConfig, SafetyConfig
from companion.control.safety import FenceStatus, Geofence, SetpointLimiter
from companion.msg.setpoint import VelocitySetpoint

FENCE = Geofence(radius_m=10.0, min_alt_m=-1.0, max_alt_m=20.0, centre_ne_m=(5.0, -5.0))


@pytest.mark.parametrize(
    "position",
    [
        (5.0, -5.0, -10.0),
        (14.9, -5.0, -1.0),
        (5.0, 4.9, 0.0),
        (5.0, -5.0, 0.99),
        (5.0, -5.0, -19.9),
    ],
)
def test_inside_positions(position: tuple[float, float, float]) -> None:
    assert FENCE.check(position) == FenceStatus(True)


@pytest.mark.parametrize(
    ("position", "word"),
    [
        ((15.1, -5.0, -5.0), "radius"),
        ((5.0 + 7.2, -5.0 - 7.2, -5.0), "radius"),  # 10.2 m on the diagonal
        ((5.0, -5.0, -20.5), "above"),
        ((5.0, -5.0, 1.5), "below"),
        ((math.nan, 0.0, -5.0), "unknown"),
        ((0.0, 0.0, math.inf), "unknown"),
    ],
)
def test_outside_positions_say_why(position: tuple[float, float, float], word: str) -> None:
    status = FENCE.check(position)
    assert not status.inside
    assert status.reason is not None and word in status.reason


def test_fence_from_config_is_centred_where_asked() -> None:
    cfg = SafetyConfig(fence_radius_m=3.0, fence_min_alt_m=0.0, fence_max_alt_m=5.0)
    fence = Geofence.from_config(cfg, centre_ne_m=(100.0, 0.0))
    assert fence.check((102.0, 0.0, -1.0)).inside
    assert not fence.check((0.0, 0.0, -1.0)).inside


def test_fence_refuses_empty_shapes() -> None:
    with pytest.raises(ValueError):
        Geofence(radius_m=0.0, min_alt_m=0.0, max_alt_m=1.0)
    with pytest.raises(ValueError):
        Geofence(radius_m=1.0, min_alt_m=2.0, max_alt_m=1.0)


def test_fence_status_has_a_reason_exactly_when_outside() -> None:
    with pytest.raises(ValueError):
        FenceStatus(False)
    with pytest.raises(ValueError):
        FenceStatus(True, "why")


CMDS = CommandsConfig(v_xy_max_m_s=2.0, v_z_max_m_s=1.0, yaw_rate_max_rad_s=0.5)


def test_limiter_clips_to_command_limits_and_counts() -> None:
    limiter = SetpointLimiter(CMDS, SafetyConfig())
    out = limiter.apply(VelocitySetpoint(5.0, -3.0, 2.0, -1.0), dt_s=0.1)
    assert out.as_tuple() == (2.0, -2.0, 1.0, -0.5)
    assert limiter.limited_count == 4
    assert limiter.apply(VelocitySetpoint(0.5, 0.5, 0.5, 0.1), dt_s=0.1).as_tuple() == (
        0.5,
        0.5,
        0.5,
        0.1,
    )
    assert limiter.limited_count == 4


def test_limiter_without_rate_limits_passes_steps_through() -> None:
    limiter = SetpointLimiter(CMDS, SafetyConfig())
    limiter.apply(VelocitySetpoint.zero(), dt_s=0.1)
    assert limiter.apply(VelocitySetpoint(2.0, 0.0, -1.0, 0.5), dt_s=0.1).as_tuple() == (
        2.0,
        0.0,
        -1.0,
        0.5,
    )


def test_limiter_limits_rate_of_change_per_axis() -> None:
    safety = SafetyConfig(max_accel_xy_m_s2=1.0, max_accel_z_m_s2=0.5, max_yaw_accel_rad_s2=0.0)
    limiter = SetpointLimiter(CMDS, safety)
    limiter.apply(VelocitySetpoint.zero(), dt_s=0.1)  # the first one is taken as it is
    out = limiter.apply(VelocitySetpoint(2.0, -2.0, 1.0, 0.5), dt_s=0.1)
    assert out.as_tuple() == pytest.approx((0.1, -0.1, 0.05, 0.5))  # yaw: no rate limit
    # Ramps up to the target and stays there.
    for _ in range(40):
        out = limiter.apply(VelocitySetpoint(2.0, -2.0, 1.0, 0.5), dt_s=0.1)
    assert out.as_tuple() == pytest.approx((2.0, -2.0, 1.0, 0.5))


def test_limiter_reset_forgets_the_last_setpoint() -> None:
    limiter = SetpointLimiter(CMDS, SafetyConfig(max_accel_xy_m_s2=1.0))
    limiter.apply(VelocitySetpoint.zero(), dt_s=0.1)
    limiter.reset()
    assert limiter.apply(VelocitySetpoint(2.0, 0.0, 0.0, 0.0), dt_s=0.1).forward_m_s == 2.0


def test_limiter_output_always_within_limits(rng: np.random.Generator) -> None:
    limiter = SetpointLimiter(CMDS, SafetyConfig(max_accel_xy_m_s2=3.0, max_accel_z_m_s2=2.0))
    for _ in range(300):
        out = limiter.apply(VelocitySetpoint(*rng.uniform(-10, 10, 4)), dt_s=rng.uniform(0, 0.2))
        f, r, d, y = out.as_tuple()
        assert abs(f) <= 2.0 and abs(r) <= 2.0 and abs(d) <= 1.0 and abs(y) <= 0.5
