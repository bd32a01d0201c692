"""Joystick commands, the transforms one by one, and the mapping to velocity setpoints."""

from __future__ import annotations

import logging
import math

import numpy as np
import pytest

from companion.commands import CommandMapper, clip, deadband, expo, sanitize, scale
from companion.config import CommandsConfig
from companion.msg.command import AXES, JoystickCommand

CFG = CommandsConfig(
    v_xy_max_m_s=2.0, v_z_max_m_s=1.0, yaw_rate_max_rad_s=0.8, deadband=0.1, expo=0.3
)


# --- JoystickCommand -----------------------------------------------------------------------


def test_command_round_trips_through_array_in_axes_order() -> None:
    cmd = JoystickCommand(roll=0.1, pitch=-0.2, yaw=0.3, throttle=-0.4)
    arr = cmd.to_array()
    assert AXES == ("roll", "pitch", "yaw", "throttle")
    assert arr.tolist() == [0.1, -0.2, 0.3, -0.4]
    assert JoystickCommand.from_array(arr) == cmd


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_command_refuses_non_finite(bad: float) -> None:
    with pytest.raises(ValueError, match="sanitize"):
        JoystickCommand(0.0, bad, 0.0, 0.0)


@pytest.mark.parametrize("bad", [1.0001, -1.5, 7])
def test_command_refuses_out_of_range(bad: float) -> None:
    with pytest.raises(ValueError, match=r"\[-1, 1\]"):
        JoystickCommand(0.0, 0.0, 0.0, bad)


def test_command_refuses_non_numbers_and_wrong_length() -> None:
    with pytest.raises(TypeError):
        JoystickCommand(0.0, "0.5", 0.0, 0.0)  # type: ignore[arg-type]
    with pytest.raises(TypeError):
        JoystickCommand(True, 0.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="4 values"):
        JoystickCommand.from_array([0.0, 0.0, 0.0])


def test_command_accepts_numpy_scalars_and_stores_floats() -> None:
    cmd = JoystickCommand(np.float32(0.5), np.int64(1), 0, -1)
    assert type(cmd.roll) is float and type(cmd.pitch) is float
    assert cmd.to_array().dtype == np.float64


def test_command_is_frozen() -> None:
    cmd = JoystickCommand.neutral()
    with pytest.raises(AttributeError):
        cmd.roll = 1.0  # type: ignore[misc]


def test_sanitize_replaces_non_finite_by_zero_and_clamps_with_counts() -> None:
    cmd, issues = sanitize([math.nan, 3.0, -math.inf, -1.2])
    assert cmd == JoystickCommand(0.0, 1.0, 0.0, -1.0)
    assert (issues.non_finite, issues.clamped) == (2, 2)
    assert issues.any


def test_sanitize_leaves_valid_values_alone() -> None:
    cmd, issues = sanitize(np.array([0.25, -1.0, 1.0, 0.0]))
    assert cmd.to_array().tolist() == [0.25, -1.0, 1.0, 0.0]
    assert not issues.any


# --- the transforms alone ------------------------------------------------------------------


def test_deadband_zeroes_centre_and_keeps_ends_continuous() -> None:
    x = np.array([-1.0, -0.1, -0.05, 0.0, 0.05, 0.1, 0.55, 1.0])
    out = deadband(x, 0.1)
    assert out.tolist() == pytest.approx([-1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.5, 1.0])
    # Continuous just outside the band, and monotonic.
    assert deadband(np.array([0.1001]), 0.1)[0] == pytest.approx(0.0, abs=1e-3)
    grid = np.linspace(-1, 1, 201)
    assert np.all(np.diff(deadband(grid, 0.1)) >= 0)


def test_deadband_zero_width_is_identity_and_bad_width_refused() -> None:
    x = np.linspace(-1, 1, 11)
    assert deadband(x, 0.0) == pytest.approx(x)
    with pytest.raises(ValueError):
        deadband(x, 1.0)


def test_expo_keeps_ends_and_softens_centre() -> None:
    x = np.array([-1.0, -0.5, 0.0, 0.5, 1.0])
    assert expo(x, 0.0) == pytest.approx(x)
    out = expo(x, 1.0)
    assert out.tolist() == pytest.approx([-1.0, -0.125, 0.0, 0.125, 1.0])
    assert abs(expo(np.array([0.5]), 0.3)[0]) < 0.5
    with pytest.raises(ValueError):
        expo(x, 1.5)


def test_scale_multiplies_per_axis() -> None:
    assert scale(np.array([0.5, -1.0]), np.array([2.0, 3.0])).tolist() == [1.0, -3.0]


def test_clip_limits_and_counts_including_non_finite() -> None:
    out, changed = clip(np.array([3.0, -0.5, math.nan, -math.inf]), np.array([2.0, 1.0, 1.0, 1.0]))
    assert out.tolist() == [2.0, -0.5, 0.0, 0.0]  # non-finite -> 0, as in sanitize
    assert changed == 3


# --- the mapper ------------------------------------------------------------------------------


def test_full_sticks_map_to_limits_with_design_signs() -> None:
    m = CommandMapper(CFG)
    sp = m.to_setpoint(JoystickCommand(roll=1.0, pitch=1.0, yaw=1.0, throttle=1.0))
    assert sp.right_m_s == pytest.approx(2.0)  # roll +1 = move right
    assert sp.forward_m_s == pytest.approx(2.0)  # pitch +1 = forward
    assert sp.yaw_rate_rad_s == pytest.approx(0.8)  # yaw +1 = clockwise (positive in FRD)
    assert sp.down_m_s == pytest.approx(-1.0)  # throttle +1 = climb = negative down
    sp = m.to_setpoint(JoystickCommand(roll=-1.0, pitch=-1.0, yaw=-1.0, throttle=-1.0))
    assert sp.as_tuple() == pytest.approx((-2.0, -2.0, 1.0, -0.8))


def test_each_axis_moves_only_its_own_setpoint_component() -> None:
    m = CommandMapper(CommandsConfig(deadband=0.0, expo=0.0))
    assert m.to_setpoint(JoystickCommand(0.5, 0, 0, 0)).as_tuple() == (0.0, 1.0, 0.0, 0.0)
    assert m.to_setpoint(JoystickCommand(0, 0.5, 0, 0)).as_tuple() == (1.0, 0.0, 0.0, 0.0)
    assert m.to_setpoint(JoystickCommand(0, 0, 0.5, 0)).as_tuple() == (0.0, 0.0, 0.0, 0.5)
    assert m.to_setpoint(JoystickCommand(0, 0, 0, -0.5)).as_tuple() == (0.0, 0.0, 0.5, 0.0)


def test_centred_sticks_within_deadband_give_an_exact_zero_setpoint() -> None:
    sp = CommandMapper(CFG).to_setpoint(JoystickCommand(0.05, -0.09, 0.02, -0.1))
    assert sp.as_tuple() == (0.0, 0.0, 0.0, 0.0)
    assert math.copysign(1.0, sp.down_m_s) == 1.0  # +0.0, not -0.0


def test_mapper_applies_deadband_then_expo_then_scale() -> None:
    m = CommandMapper(CFG)
    sp = m.to_setpoint(JoystickCommand(0.0, 0.55, 0.0, 0.0))
    shaped = expo(deadband(np.array([0.55]), 0.1), 0.3)[0]
    assert sp.forward_m_s == pytest.approx(shaped * 2.0)


def test_garbage_never_produces_a_setpoint_outside_limits(rng: np.random.Generator) -> None:
    m = CommandMapper(CFG)
    specials = np.array([math.nan, math.inf, -math.inf, 1e308, -1e308, 1.0000001, -5.0])
    for _ in range(500):
        values = rng.uniform(-3, 3, size=4)
        mask = rng.random(4) < 0.4
        values[mask] = rng.choice(specials, size=int(mask.sum()))
        sp = m.from_values(values)
        fwd, right, down, yaw_rate = sp.as_tuple()
        assert all(math.isfinite(v) for v in sp.as_tuple())
        assert abs(fwd) <= 2.0 and abs(right) <= 2.0
        assert abs(down) <= 1.0 and abs(yaw_rate) <= 0.8
    assert m.counts.commands == 500
    assert m.counts.non_finite_axes > 0 and m.counts.clamped_axes > 0


def test_mapper_counts_and_logs_repairs(caplog: pytest.LogCaptureFixture) -> None:
    m = CommandMapper(CFG, log_every=2)
    with caplog.at_level(logging.WARNING, logger="companion.commands"):
        m.from_values([math.nan, 2.0, 0.0, 0.0])
        m.from_values([0.0, 0.0, -math.inf, 0.0])
        m.from_values([0.0, 0.0, 0.0, 9.0])
        m.from_values([0.1, 0.2, 0.3, 0.4])  # valid: not counted, not logged
    c = m.counts
    assert (c.commands, c.non_finite_axes, c.clamped_axes) == (4, 2, 2)
    repairs = [r for r in caplog.records if "repaired" in r.getMessage()]
    assert len(repairs) == 2  # the first and the third repair (every 2nd)
    assert "Check the policy" in repairs[0].getMessage()


def test_mapper_maps_valid_values_like_the_command() -> None:
    m = CommandMapper(CFG)
    values = [0.3, -0.7, 0.2, 0.9]
    assert m.from_values(values) == m.to_setpoint(JoystickCommand.from_array(values))
    assert m.counts.non_finite_axes == 0 and m.counts.clamped_axes == 0


def test_command_from_values_repairs_and_counts_without_mapping() -> None:
    m = CommandMapper(CFG)
    cmd = m.command_from_values(np.array([math.nan, 1.5, -0.5, 0.25], dtype=np.float32))
    assert cmd == JoystickCommand(0.0, 1.0, -0.5, 0.25)
    c = m.counts
    assert (c.commands, c.non_finite_axes, c.clamped_axes) == (0, 1, 1)
