"""How a watching pilot judges the pad's own motion: where it is on the ground, followed in time.

A person landing on a moving ground vehicle sees the pad slide across the picture while they
hold their own speed; they learn its speed and lead it, as a driver matches a lane. Here the
pad's ground position is the vehicle's position estimate plus the pad's offset in the picture,
and an alpha-beta tracker (the classic fixed-gain form of a constant-velocity Kalman filter)
follows its position and velocity. Both come from what the pilot has (the picture and the
vehicle's own estimate), never from the ground vehicle's truth; where the estimate drifts the
pad's velocity drifts with it, and the velocity *relative* to the pad stays right.
"""

from __future__ import annotations

import math

import numpy as np

ALPHA = 0.3
"""Position gain: a pad seen this much nearer its sighting than its prediction."""
BETA = ALPHA * ALPHA / (2.0 - ALPHA)
"""Velocity gain, critically damped for ALPHA (Benedict-Bordner): about a second at 10 Hz to
settle, with a sighting's scatter of a few centimetres worth ~0.05 m/s."""
MAX_GAP_S = 1.0
"""A pad unseen this long is picked up again where it is seen, keeping the speed a person
remembers; shorter gaps are bridged by the prediction."""


def pad_ground_position(forward_m: float, right_m: float, position_ne_m: tuple[float, float],
                        yaw_rad: float) -> np.ndarray:
    """The pad's (north, east) from the vehicle's position and its heading-frame offset."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    return np.array([position_ne_m[0] + c * forward_m - s * right_m, position_ne_m[1] + s * forward_m + c * right_m])


def heading_frame(vector_ne: np.ndarray, yaw_rad: float) -> np.ndarray:
    """A (north, east) vector as (forward, right) for this heading."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    return np.array([c * vector_ne[0] + s * vector_ne[1], -s * vector_ne[0] + c * vector_ne[1]])


class PadMotion:
    """The pad's ground position and velocity from its sightings (alpha-beta tracker).

    ``velocity_ne_m_s`` is zero until the pad has been seen twice, so a pilot who has not yet
    seen it move flies as over a still pad.
    """

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self._position_ne = np.zeros(2)
        self._velocity_ne = np.zeros(2)
        self._seen_ms: int | None = None

    @property
    def velocity_ne_m_s(self) -> np.ndarray:
        return self._velocity_ne.copy()

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
        predicted = self._position_ne + self._velocity_ne * dt_s
        residual = np.asarray(pad_ne_m, dtype=float) - predicted
        self._position_ne = predicted + ALPHA * residual
        self._velocity_ne = self._velocity_ne + (BETA / dt_s) * residual

    def moved_since(self, since_ms: int, now_ms: int) -> np.ndarray:
        """How far (north, east) the pad has driven from ``since_ms`` to ``now_ms`` at its speed."""
        return self._velocity_ne * max(0.0, (now_ms - since_ms) / 1e3)
