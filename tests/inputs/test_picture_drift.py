"""The drift a pilot judges from the picture: the motion relative to the pad minus the reading."""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.inputs.pad_view import PadEstimate
from companion.inputs.picture_drift import (
    MAX_DRIFT_M_S,
    MAX_GAP_S,
    PictureDrift,
    offset_ne,
    to_heading_frame,
)


def view_at(vehicle_ne: np.ndarray, yaw_rad: float, height_m: float = 1.0) -> PadEstimate:
    """The pad at (0, 0) seen from ``vehicle_ne`` with heading ``yaw_rad``."""
    rel = -vehicle_ne
    forward, right = to_heading_frame(rel, yaw_rad)
    return PadEstimate(float(forward), float(right), height_m, 0.1, False)


def fly(drift: PictureDrift, true_ne_m_s: np.ndarray, reading_ne_m_s: np.ndarray, seconds: float,
        yaw_rad: float = 0.7, height_m: float = 1.0, dt_s: float = 0.1) -> None:
    pos = np.array([0.3, -0.2])
    for k in range(int(seconds / dt_s)):
        drift.see(view_at(pos, yaw_rad, height_m), int(round(k * dt_s * 1000)), yaw_rad, tuple(reading_ne_m_s))
        pos = pos + true_ne_m_s * dt_s


def test_offset_and_heading_frame_are_inverse() -> None:
    view = PadEstimate(0.4, -0.3, 1.0, 0.2, False)
    yaw = 1.1
    assert to_heading_frame(offset_ne(view, yaw), yaw) == pytest.approx([0.4, -0.3])
    assert offset_ne(PadEstimate(1.0, 0.0, 1.0, 0.0, False), math.pi / 2) == pytest.approx([0.0, 1.0], abs=1e-12)


def test_a_reading_that_misses_the_true_motion_is_judged_as_drift() -> None:
    """The vehicle truly moves 0.3 m/s east while its reading says 0.1 m/s north."""
    drift = PictureDrift(0.5)
    fly(drift, np.array([0.0, 0.3]), np.array([0.1, 0.0]), seconds=5.0)
    assert drift.drift_ne_m_s == pytest.approx([-0.1, 0.3], abs=0.01)
    yaw = 0.7
    assert drift.drift_fr(yaw, 4900) == pytest.approx(to_heading_frame(np.array([-0.1, 0.3]), yaw), abs=0.01)
    assert np.hypot(*drift.drift_fr(yaw, 4900 + 3500)) == pytest.approx(np.hypot(-0.1, 0.3) * math.exp(-3.0), abs=0.01)


def test_a_true_reading_is_no_drift_and_high_up_the_drift_is_learned_slower() -> None:
    still = PictureDrift(0.5)
    fly(still, np.array([0.2, -0.1]), np.array([0.2, -0.1]), seconds=3.0)
    assert np.hypot(*still.drift_ne_m_s) < 1e-9
    low, high = PictureDrift(0.5), PictureDrift(0.5)
    fly(low, np.array([0.3, 0.0]), np.zeros(2), seconds=0.5, height_m=1.0)
    fly(high, np.array([0.3, 0.0]), np.zeros(2), seconds=0.5, height_m=6.0)
    assert 0.0 < high.drift_ne_m_s[0] < low.drift_ne_m_s[0] < 0.3


def test_gaps_and_unseen_pads_keep_the_drift_and_it_is_bounded() -> None:
    drift = PictureDrift(0.5)
    drift.see(view_at(np.zeros(2), 0.0), 0, 0.0, (0.0, 0.0))
    drift.see(view_at(np.array([1.0, 0.0]), 0.0), int(MAX_GAP_S * 1000) + 100, 0.0, (0.0, 0.0))
    assert drift.drift_ne_m_s == pytest.approx([0.0, 0.0])  # the pad was lost between: not differenced
    drift.see(None, 2000, 0.0, (0.0, 0.0))
    assert drift.drift_ne_m_s == pytest.approx([0.0, 0.0])
    drift.see(view_at(np.array([1.0, 0.0]), 0.0), 2000, 0.0, (0.0, 0.0))
    drift.see(view_at(np.array([5.0, 0.0]), 0.0), 2100, 0.0, (0.0, 0.0))  # 40 m/s: a stray sighting
    assert np.hypot(*drift.drift_ne_m_s) == pytest.approx(MAX_DRIFT_M_S)
    drift.reset()
    assert drift.drift_ne_m_s == pytest.approx([0.0, 0.0])


def test_a_time_constant_must_be_positive() -> None:
    with pytest.raises(ValueError, match="time constant"):
        PictureDrift(0.0)
