"""The pad's motion as a watching pilot judges it (companion/inputs/pad_motion.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.inputs.pad_motion import MAX_GAP_S, PadMotion, heading_frame, pad_ground_position


def test_a_pad_driving_steadily_is_followed_to_its_speed(rng: np.random.Generator) -> None:
    """Sightings 0.05 m apart at random (what the picture gives near the pad) of a pad driving
    (1.0, -0.5) m/s, at the companion's 10.5 Hz: its speed within 0.1 m/s after 3 s."""
    motion, velocity = PadMotion(), np.array([1.0, -0.5])
    for k in range(32):
        t_ms = round(k * 1000 / 10.5)
        motion.update(velocity * t_ms / 1e3 + rng.normal(0.0, 0.05, 2), t_ms)
    assert np.linalg.norm(motion.velocity_ne_m_s - velocity) < 0.1, motion.velocity_ne_m_s


def test_unseen_it_is_still_until_seen_twice_and_the_same_frame_counts_once() -> None:
    motion = PadMotion()
    assert motion.velocity_ne_m_s.tolist() == [0.0, 0.0]
    motion.update(np.array([1.0, 2.0]), 0)
    motion.update(np.array([5.0, 2.0]), 0)  # the same time again: nothing new
    assert motion.velocity_ne_m_s.tolist() == [0.0, 0.0]
    motion.update(np.array([1.1, 2.0]), 100)
    assert motion.velocity_ne_m_s[0] > 0.0


def test_after_a_long_gap_the_pad_is_picked_up_where_seen_keeping_its_speed() -> None:
    motion = PadMotion()
    for k in range(40):
        motion.update(np.array([0.1 * k, 0.0]), 100 * k)  # 1 m/s north
    speed = motion.velocity_ne_m_s.copy()
    gap_ms = 3900 + round(MAX_GAP_S * 1000) + 500
    motion.update(np.array([-20.0, 0.0]), gap_ms)  # seen again far from where it would be
    assert motion.velocity_ne_m_s.tolist() == speed.tolist()  # a jump is no speed
    motion.update(np.array([-19.9, 0.0]), gap_ms + 100)
    assert motion.velocity_ne_m_s[0] == pytest.approx(1.0, abs=0.05)


def test_how_far_it_has_driven_since() -> None:
    motion = PadMotion()
    for k in range(60):
        motion.update(np.array([0.0, 0.05 * k]), 100 * k)  # 0.5 m/s east
    assert motion.moved_since(5000, 7000) == pytest.approx([0.0, 1.0], abs=0.03)
    assert motion.moved_since(7000, 5000).tolist() == [0.0, 0.0]  # never backwards in time


def test_frames() -> None:
    yaw = math.radians(90.0)  # facing east: forward is east, right is south
    assert pad_ground_position(2.0, 1.0, (10.0, 20.0), yaw) == pytest.approx([9.0, 22.0])
    assert heading_frame(np.array([0.0, 1.0]), yaw) == pytest.approx([1.0, 0.0])
    assert heading_frame(np.array([1.0, 0.0]), yaw) == pytest.approx([0.0, -1.0])
