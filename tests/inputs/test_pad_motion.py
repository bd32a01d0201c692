"""The pad's motion as a watching pilot judges it (companion/inputs/pad_motion.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.inputs.pad_motion import (
    MAX_GAP_S,
    Course,
    PadMotion,
    heading_frame,
    pad_ground_position,
    rotate,
)


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


def test_a_pad_driving_a_curve_is_followed_with_its_turn_and_predicted_along_it(rng: np.random.Generator) -> None:
    """A ground vehicle driving a curve at 1.5 m/s and 0.1 rad/s, seen to 0.02 m for 6 s: the
    turn rate is learned, and 3 s unseen (the set-down, the pad filling the view) the pad is
    predicted on its curve to ~0.1 m (median of 20 runs), where a straight line misses by 0.7 m."""
    speed, turn = 1.5, 0.1

    def pad(t_s: float) -> np.ndarray:  # on a circle of radius speed / turn, starting north-bound
        r = speed / turn
        return np.array([r * math.sin(turn * t_s), r * (1.0 - math.cos(turn * t_s))])

    turns, curved, straight, course = [], [], [], []
    for _ in range(20):
        motion, last_ms = PadMotion(), 0
        for k in range(63):
            last_ms = round(k * 1000 / 10.5)
            motion.update(pad(last_ms / 1e3) + rng.normal(0.0, 0.02, 2), last_ms)
        later_ms, seen = last_ms + 3000, pad(last_ms / 1e3)
        turns.append(motion.turn_rad_s)
        curved.append(np.linalg.norm(seen + motion.moved_since(last_ms, later_ms) - pad(later_ms / 1e3)))
        straight.append(np.linalg.norm(seen + motion.velocity_ne_m_s * 3.0 - pad(later_ms / 1e3)))
        v = motion.velocity_ne_at(later_ms)
        course.append(math.atan2(v[1], v[0]) - turn * later_ms / 1e3)
    assert np.median(turns) == pytest.approx(turn, abs=0.02)
    assert np.median(curved) < 0.15, np.round(curved, 2)
    assert np.median(straight) > 0.5
    assert abs(np.median(course)) < 0.05  # its velocity turned on with the pad's


def test_a_still_pad_learns_no_turn(rng: np.random.Generator) -> None:
    motion = PadMotion()
    for k in range(60):
        motion.update(rng.normal(0.0, 0.05, 2), 100 * k)
    assert abs(motion.turn_rad_s) < 0.05


def test_a_quarter_circle() -> None:
    """1 m/s north turning clockwise at pi/2 rad/s for 1 s: a quarter of a circle of radius 2/pi."""
    r = 2.0 / math.pi
    assert Course(np.array([1.0, 0.0]), math.pi / 2).driven(0.0, 1.0) == pytest.approx([r, r], abs=1e-6)
    assert Course(np.array([1.0, 0.0])).driven(0.5, 2.0) == pytest.approx([1.5, 0.0])
    assert Course(np.array([1.0, 0.0])).driven(2.0, 1.0).tolist() == [0.0, 0.0]
    assert rotate(np.array([1.0, 0.0]), math.pi / 2) == pytest.approx([0.0, 1.0])  # north -> east: clockwise
