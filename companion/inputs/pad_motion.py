"""How a watching pilot judges the pad's own motion: where it is on the ground, followed in time.

A person landing on a moving ground vehicle sees the pad slide across the picture while they
hold their own speed; they learn its speed and lead it, as a driver matches a lane. Here the
pad's ground position is the vehicle's position estimate plus the pad's offset in the picture,
and an alpha-beta tracker (the classic fixed-gain form of a constant-velocity Kalman filter)
follows its position and velocity, with the rate its course turns at (a vehicle driving a curve
keeps turning while the pad fills the view at the set-down and only its rim is seen; a pilot
extrapolates the curve). Its speed is taken as steady: extrapolating a change of speed learned
over two seconds made the set-down worse on a vehicle whose speed swings (it commits near the
slowest point, where the change turns round; results/moving-pad/lead-check/). Both come from what the pilot has (the picture and the
vehicle's own estimate), never from the ground vehicle's truth; where the estimate drifts the
pad's velocity drifts with it, and the velocity *relative* to the pad stays right.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

ALPHA = 0.3
"""Position gain: a pad seen this much nearer its sighting than its prediction."""
BETA = ALPHA * ALPHA / (2.0 - ALPHA)
"""Velocity gain, critically damped for ALPHA (Benedict-Bordner): about a second at 10 Hz to
settle, with a sighting's scatter of a few centimetres worth ~0.05 m/s."""
TURN_GAIN = 0.05
"""Share of a sighting's change of course taken into the turn rate (about two seconds at 10 Hz:
the course of a pad seen to a few centimetres is noisy from sighting to sighting)."""
TURN_MIN_SPEED_M_S = 0.3
"""Below this speed the course is noise: the turn rate learned fades instead."""
TURN_MAX_RAD_S = 0.5
"""The fastest turn believed (a car's tight curve at a few m/s)."""
MAX_GAP_S = 1.0
"""A pad unseen this long is picked up again where it is seen, keeping the speed a person
remembers; shorter gaps are bridged by the prediction."""
PATH_STEPS = 16
"""Simpson intervals for a predicted path (seconds long, gently curved: exact to far below a mm)."""


@dataclass(frozen=True)
class Course:
    """How the pad drives at one moment: its velocity and the rate its course turns at
    (clockwise seen from above)."""

    velocity_ne_m_s: np.ndarray
    turn_rad_s: float = 0.0

    def velocity_after(self, t_s: float) -> np.ndarray:
        """The velocity ``t_s`` later, keeping the turn."""
        return rotate(self.velocity_ne_m_s, self.turn_rad_s * t_s)

    def driven(self, start_s: float, end_s: float) -> np.ndarray:
        """How far (north, east) it drives from ``start_s`` to ``end_s`` (Simpson's rule)."""
        if end_s <= start_s:
            return np.zeros(2)
        ts = np.linspace(start_s, end_s, PATH_STEPS + 1)
        weights = np.ones(PATH_STEPS + 1)
        weights[1:-1:2], weights[2:-1:2] = 4.0, 2.0
        velocities = np.array([self.velocity_after(float(t)) for t in ts])
        return (weights @ velocities) * (end_s - start_s) / (3.0 * PATH_STEPS)


def pad_ground_position(forward_m: float, right_m: float, position_ne_m: tuple[float, float],
                        yaw_rad: float) -> np.ndarray:
    """The pad's (north, east) from the vehicle's position and its heading-frame offset."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    return np.array([position_ne_m[0] + c * forward_m - s * right_m, position_ne_m[1] + s * forward_m + c * right_m])


def rotate(vector_ne: np.ndarray, angle_rad: float) -> np.ndarray:
    """A (north, east) vector turned clockwise seen from above by ``angle_rad``."""
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.array([c * vector_ne[0] - s * vector_ne[1], s * vector_ne[0] + c * vector_ne[1]])


def heading_frame(vector_ne: np.ndarray, yaw_rad: float) -> np.ndarray:
    """A (north, east) vector as (forward, right) for this heading."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    return np.array([c * vector_ne[0] + s * vector_ne[1], -s * vector_ne[0] + c * vector_ne[1]])


class PadMotion:
    """The pad's ground position and course from its sightings (an alpha-beta tracker whose
    prediction keeps the course's turn).

    The velocity is zero until the pad has been seen twice, so a pilot who has not yet seen it
    move flies as over a still pad; between sightings its course goes on as learned.
    """

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self._position_ne = np.zeros(2)
        self.course = Course(np.zeros(2))
        self._seen_ms: int | None = None

    @property
    def velocity_ne_m_s(self) -> np.ndarray:
        """The velocity at the last sighting."""
        return self.course.velocity_ne_m_s.copy()

    @property
    def turn_rad_s(self) -> float:
        return self.course.turn_rad_s

    def velocity_ne_at(self, now_ms: int) -> np.ndarray:
        """The velocity now: the last sighting's, driven on as learned since."""
        if self._seen_ms is None:
            return self.velocity_ne_m_s
        return self.course.velocity_after(max(0.0, (now_ms - self._seen_ms) / 1e3))

    def update(self, pad_ne_m: np.ndarray, now_ms: int) -> None:
        """One sighting of the pad at ``pad_ne_m`` (metres) at vehicle time ``now_ms``."""
        seen = self._seen_ms
        dt_s = math.inf if seen is None else (now_ms - seen) / 1e3
        if dt_s <= 0.0:
            return  # the same frame again (or time running back): nothing new
        self._seen_ms = now_ms
        if dt_s > MAX_GAP_S:
            self._position_ne = np.asarray(pad_ne_m, dtype=float).copy()
            return
        before = self.course
        predicted = self._position_ne + before.driven(0.0, dt_s)
        residual = np.asarray(pad_ne_m, dtype=float) - predicted
        self._position_ne = predicted + ALPHA * residual
        after = before.velocity_after(dt_s) + (BETA / dt_s) * residual
        self.course = self._trends(before, after, dt_s)

    @staticmethod
    def _trends(before: Course, after: np.ndarray, dt_s: float) -> Course:
        """The new velocity with the course's change over this sighting taken into the turn."""
        was = before.velocity_ne_m_s
        if min(float(np.hypot(*was)), float(np.hypot(*after))) < TURN_MIN_SPEED_M_S:
            return Course(after, before.turn_rad_s * (1.0 - TURN_GAIN))
        turn = math.atan2(was[0] * after[1] - was[1] * after[0], float(was @ after)) / dt_s
        learned = before.turn_rad_s + TURN_GAIN * (turn - before.turn_rad_s)
        return Course(after, float(np.clip(learned, -TURN_MAX_RAD_S, TURN_MAX_RAD_S)))

    def moved_since(self, since_ms: int, now_ms: int) -> np.ndarray:
        """How far (north, east) the pad has driven from ``since_ms`` to ``now_ms`` on its course
        (nothing before it was seen or backwards in time)."""
        if self._seen_ms is None or now_ms <= since_ms:
            return np.zeros(2)
        return self.course.driven((since_ms - self._seen_ms) / 1e3, (now_ms - self._seen_ms) / 1e3)
