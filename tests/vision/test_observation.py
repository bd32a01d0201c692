"""The 15-value observation: order, normalisation, the "pad not visible" code, validation."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from companion.msg.observation import (
    OBS_DIM,
    OBS_NAMES,
    OBS_SCALES,
    PAD_NOT_VISIBLE,
    Observation,
    pad_visible,
    wrap_angle_rad,
)
from companion.msg.pad import PadDetection


def make(pad: PadDetection | None = None, **overrides) -> Observation:
    fields = dict(
        position_ned_m=(1.0, -2.0, -8.0),
        attitude_rad=(0.1, -0.2, 0.5),
        velocity_ned_m_s=(0.5, 1.0, -0.25),
        rates_frd_rad_s=(0.01, 0.02, -0.3),
        pad=pad,
        image_size_px=(320, 240),
        time_boot_ms=1500,
    )
    fields.update(overrides)
    return Observation(**fields)


def test_dimension_and_order() -> None:
    assert OBS_DIM == 15 == len(OBS_NAMES) == len(set(OBS_NAMES))
    assert OBS_NAMES[:3] == ("north_m", "east_m", "down_m")
    assert OBS_NAMES[3:6] == ("roll_rad", "pitch_rad", "yaw_rad")
    assert OBS_NAMES[12:] == ("pad_u", "pad_v", "pad_radius")
    assert len(OBS_SCALES) == 12


def test_vector_values_follow_the_documented_scales() -> None:
    vec = make(PadDetection(159.5, 119.5, 30.0, False)).to_vector()
    assert vec.dtype == np.float32 and vec.shape == (OBS_DIM,)
    expected = [0.1, -0.2, -0.8, 0.1 / math.pi, -0.2 / math.pi, 0.5 / math.pi, 0.1, 0.2, -0.05,
                0.01 / math.pi, 0.02 / math.pi, -0.3 / math.pi, 0.0, 0.0, 0.25]
    np.testing.assert_allclose(vec, expected, rtol=1e-6, atol=1e-7)
    assert pad_visible(vec)


def test_pad_position_is_relative_to_the_image_centre_and_edges() -> None:
    right_bottom = make(PadDetection(319.5, 239.5, 10.0, False)).to_vector()
    assert right_bottom[12:14] == pytest.approx([1.0, 1.0])
    left_top = make(PadDetection(-0.5, -0.5, 10.0, True)).to_vector()
    assert left_top[12:14] == pytest.approx([-1.0, -1.0])


def test_not_visible_encoding() -> None:
    vec = make(None).to_vector()
    assert tuple(vec[12:]) == PAD_NOT_VISIBLE == (0.0, 0.0, -1.0)
    assert not pad_visible(vec)


def test_partial_pad_far_outside_and_huge_pad_are_clipped() -> None:
    vec = make(PadDetection(-900.0, 2000.0, 800.0, True)).to_vector()
    assert vec[12:].tolist() == [-2.0, 2.0, 2.0]


def test_yaw_is_wrapped() -> None:
    assert wrap_angle_rad(3 * math.pi / 2) == pytest.approx(-math.pi / 2)
    vec = make(attitude_rad=(0.0, 0.0, 3 * math.pi / 2)).to_vector()
    assert vec[5] == pytest.approx(-0.5)


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
def test_non_finite_telemetry_is_an_error(bad: float) -> None:
    for name in ("position_ned_m", "attitude_rad", "velocity_ned_m_s", "rates_frd_rad_s"):
        with pytest.raises(ValueError, match=name):
            make(**{name: (0.0, bad, 0.0)})


def test_other_invalid_inputs() -> None:
    with pytest.raises(ValueError, match="3 values"):
        make(position_ned_m=(1.0, 2.0))
    with pytest.raises(ValueError, match="image_size_px"):
        make(image_size_px=(0, 240))
    with pytest.raises(TypeError, match="PadDetection"):
        make(pad=(1.0, 2.0, 3.0))
    with pytest.raises(ValueError, match="time_boot_ms"):
        make(time_boot_ms=-1)


def test_observation_is_immutable_and_accepts_arrays() -> None:
    obs = make(position_ned_m=np.array([1.0, 2.0, 3.0]))
    assert obs.position_ned_m == (1.0, 2.0, 3.0)
    with pytest.raises(dataclasses.FrozenInstanceError):
        obs.time_boot_ms = 5  # type: ignore[misc]


def test_random_finite_inputs_never_give_nan(rng) -> None:
    for _ in range(200):
        pad = None if rng.random() < 0.3 else PadDetection(*rng.uniform(-500, 800, 2), rng.uniform(0.1, 900), False)
        obs = make(
            pad,
            position_ned_m=rng.normal(0, 50, 3), attitude_rad=rng.normal(0, 5, 3),
            velocity_ned_m_s=rng.normal(0, 10, 3), rates_frd_rad_s=rng.normal(0, 10, 3),
        )
        vec = obs.to_vector()
        assert np.all(np.isfinite(vec)) and -1.0 <= vec[5] <= 1.0
