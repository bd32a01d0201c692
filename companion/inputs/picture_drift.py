"""How a watching pilot judges the drift their ground-speed reading does not show: from the picture.

An autopilot flies a velocity setpoint with its own velocity *estimate*; where that estimate is
off the truth the vehicle drifts while its ground-speed reading (the estimate) says it holds
still. PX4 SIH's estimate is 0.2-0.3 m/s off in flight at the median and changes by 0.4 m/s
within two seconds (results/real-autopilots/RENDER.md, drift-by-picture/), faster than a
pilot's trim, which grows from a lasting offset, can follow. A person landing by the camera sees
the drift: the pad slides across the picture while the reading says still. Here the vehicle's
motion relative to the pad is the change of the pad's offset in the picture between two
sightings, and the drift is how far that is from the velocity reading, smoothed. Leaning
against it (a feed-forward of minus the drift) makes the vehicle truly do what was asked; the
speed damped is the reading plus the drift (the motion relative to the pad).

Over a moving pad the drift also holds the pad's own velocity (the motion relative to the pad
is judged, not over the ground), so leaning against it leads the pad; it is kept apart from
``lead_moving_pad`` (which follows the pad's motion itself) by the configuration.

Noise: a sighting's centre is good to about a pixel, which is ``height / focal length`` metres;
the smoothing's time constant grows with the height so the drift's scatter stays a few cm/s.
"""

from __future__ import annotations

import math

import numpy as np

from companion.inputs.pad_view import PadEstimate

MAX_GAP_S = 0.5
"""Two sightings further apart than this are not differenced (the pad was lost between them)."""
MAX_DRIFT_M_S = 1.0
"""The largest drift believed (PX4 SIH's p95 velocity error in flight: 0.56-0.74 m/s)."""
FADE_S = 1.0
"""Unseen for longer than ``MAX_GAP_S``, the drift fades with this time constant: without the
picture nothing shows it, and a stale lean pushed a vehicle that had lost the pad away from it
for 30 s (PX4 SIH, development runs: results/real-autopilots/RENDER.md)."""


def offset_ne(view: PadEstimate, yaw_rad: float) -> np.ndarray:
    """(north, east) from the vehicle to the pad, in metres."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    return np.array([c * view.forward_m - s * view.right_m, s * view.forward_m + c * view.right_m])


def to_heading_frame(ne: np.ndarray, yaw_rad: float) -> np.ndarray:
    """(north, east) as (forward, right) for the heading ``yaw_rad``."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    return np.array([c * ne[0] + s * ne[1], -s * ne[0] + c * ne[1]])


class PictureDrift:
    """The drift (true motion relative to the pad minus the velocity reading), north/east m/s."""

    def __init__(self, time_constant_s: float) -> None:
        if not time_constant_s > 0:
            raise ValueError(f"drift time constant must be > 0 s, got {time_constant_s}")
        self.time_constant_s = time_constant_s
        self.reset()

    def reset(self) -> None:
        self.drift_ne_m_s = np.zeros(2)
        self._last: tuple[int, np.ndarray, np.ndarray] | None = None  # ms, pad offset NE, reading NE

    def see(self, view: PadEstimate | None, time_ms: int, yaw_rad: float,
            velocity_ne_m_s: tuple[float, float]) -> None:
        """Take in one sighting the pilot believes (None: nothing seen, the drift is kept)."""
        if view is None:
            return
        offset, reading = offset_ne(view, yaw_rad), np.asarray(velocity_ne_m_s, dtype=float)
        last, self._last = self._last, (time_ms, offset, reading)
        if last is None:
            return
        dt_s = (time_ms - last[0]) / 1000.0
        if not 0.0 < dt_s <= MAX_GAP_S:
            return
        relative = -(offset - last[1]) / dt_s  # the vehicle's motion relative to the pad
        mismatch = relative - (reading + last[2]) / 2.0
        weight = min(1.0, dt_s / (self.time_constant_s * max(1.0, view.height_m)))
        drift = self.drift_ne_m_s + weight * (mismatch - self.drift_ne_m_s)
        size = float(np.hypot(*drift))
        self.drift_ne_m_s = drift if size <= MAX_DRIFT_M_S else drift * (MAX_DRIFT_M_S / size)

    def drift_fr(self, yaw_rad: float, time_ms: int) -> np.ndarray:
        """The drift as (forward, right) for the heading ``yaw_rad``, m/s, at ``time_ms`` (faded
        when the pad has not been seen for a while)."""
        return to_heading_frame(self.drift_ne_m_s * self.fade(time_ms), yaw_rad)

    def fade(self, time_ms: int) -> float:
        """1 while the pad is seen; then, after ``MAX_GAP_S``, falling towards 0."""
        if self._last is None:
            return 1.0
        unseen_s = (time_ms - self._last[0]) / 1000.0 - MAX_GAP_S
        return 1.0 if unseen_s <= 0 else math.exp(-unseen_s / FADE_S)
