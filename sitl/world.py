"""The task's world: a landing pad on the roof of a ground vehicle, episode starts, judging.

Pure geometry with no I/O, shared by the dynamics (terrain under the vehicle), the camera
(what to draw) and the vehicle server (ground truth). The ground vehicle is a box centred at
``position_ne(t)`` with its long side along north; the pad is a disc centred on its roof.
"""

from __future__ import annotations

import cmath
import math
from dataclasses import dataclass

import numpy as np

from sitl.config import WorldConfig


@dataclass(frozen=True)
class Touchdown:
    """Where and how the multirotor met a surface, judged against the pad."""

    ned: tuple[float, float, float]
    speed_m_s: float
    distance_to_pad_m: float
    on_pad: bool
    success: bool
    time_s: float


def _swept(rate: float, t_s: float) -> complex:
    """The integral of exp(i rate s) over s from 0 to t_s (t_s itself for a zero rate)."""
    if abs(rate) < 1e-12:
        return complex(t_s)
    return (cmath.exp(1j * rate * t_s) - 1.0) / (1j * rate)


class World:
    """Ground vehicle and pad kinematics from ``t0_s`` (the last reset).

    The velocity at ``t0_s`` is the set one (``vehicle_velocity_ne_m_s`` or :meth:`set_velocity`)
    plus an episode's drift (:meth:`restart`, the disturbance's random drive; zero by default).
    By default it stays so (constant velocity). A driving vehicle as a person sees it turns and
    changes speed: its course turns at ``vehicle_turn_rate_rad_s`` and its speed swings by the
    share ``vehicle_speed_change`` over ``vehicle_speed_change_period_s``. With the velocity as
    a complex number n + i e, v(t) = v0 (1 + a sin(k t)) exp(i w t), whose integral (the position)
    has a closed form: cheap enough for every FDM step's surface lookup. The box keeps its long
    side along north (the pad, a disc at its centre, is what the task lands on).
    """

    def __init__(self, cfg: WorldConfig) -> None:
        self.cfg = cfg
        self.set_velocity_ne = np.asarray(cfg.vehicle_velocity_ne_m_s, dtype=float)
        self.drift_ne = np.zeros(2)
        self.velocity_ne = self.set_velocity_ne
        self.origin_ne = np.zeros(2)
        self.t0_s = 0.0

    def restart(self, t_s: float, drift_ne_m_s: tuple[float, float] = (0.0, 0.0)) -> None:
        """Put the ground vehicle back at the origin at time ``t_s``, driving at its set
        velocity plus ``drift_ne_m_s`` from then on."""
        self.origin_ne = np.zeros(2)
        self.t0_s = t_s
        self.drift_ne = np.asarray(drift_ne_m_s, dtype=float)
        self._update_velocity()

    def set_velocity(self, velocity_ne_m_s: tuple[float, float], t_s: float) -> None:
        """Change the ground vehicle's set velocity from now on (the episode's drift stays added),
        keeping its position continuous (its turning and speed changes start again from now)."""
        self.origin_ne = self.position_ne(t_s)
        self.t0_s = t_s
        self.set_velocity_ne = np.asarray(velocity_ne_m_s, dtype=float)
        self._update_velocity()

    def _update_velocity(self) -> None:
        drifting = bool(np.any(self.drift_ne != 0.0))
        self.velocity_ne = self.set_velocity_ne + self.drift_ne if drifting else self.set_velocity_ne

    @property
    def _curving(self) -> bool:
        return self.cfg.vehicle_turn_rate_rad_s != 0.0 or self.cfg.vehicle_speed_change != 0.0

    def position_ne(self, t_s: float) -> np.ndarray:
        if not self._curving:  # constant velocity: the committed experiments' arithmetic, as it was
            return self.origin_ne + self.velocity_ne * (t_s - self.t0_s)
        tau, w, a = t_s - self.t0_s, self.cfg.vehicle_turn_rate_rad_s, self.cfg.vehicle_speed_change
        k = 2.0 * math.pi / self.cfg.vehicle_speed_change_period_s
        swept = _swept(w, tau) + a / 2j * (_swept(w + k, tau) - _swept(w - k, tau))  # sin = (e^ik - e^-ik) / 2i
        moved = complex(self.velocity_ne[0], self.velocity_ne[1]) * swept
        return self.origin_ne + np.array([moved.real, moved.imag])

    def velocity_at(self, t_s: float) -> np.ndarray:
        """The ground vehicle's velocity (north, east) at ``t_s``."""
        if not self._curving:
            return self.velocity_ne.copy()
        tau, w, a = t_s - self.t0_s, self.cfg.vehicle_turn_rate_rad_s, self.cfg.vehicle_speed_change
        k = 2.0 * math.pi / self.cfg.vehicle_speed_change_period_s
        v = complex(self.velocity_ne[0], self.velocity_ne[1]) * (1.0 + a * math.sin(k * tau)) * cmath.exp(1j * w * tau)
        return np.array([v.real, v.imag])

    @property
    def roof_height_m(self) -> float:
        return self.cfg.vehicle_height_m

    def pad_ned(self, t_s: float) -> np.ndarray:
        """Pad centre in NED (z is negative: the roof is above the ground)."""
        n, e = self.position_ne(t_s)
        return np.array([n, e, -self.cfg.vehicle_height_m])

    def over_roof(self, north_m: float, east_m: float, t_s: float) -> bool:
        n, e = self.position_ne(t_s)
        return (
            abs(north_m - n) <= self.cfg.vehicle_length_m / 2
            and abs(east_m - e) <= self.cfg.vehicle_width_m / 2
        )

    def surface_height_m(self, north_m: float, east_m: float, t_s: float) -> float:
        """Height above ground of whatever is below (roof or ground)."""
        return self.cfg.vehicle_height_m if self.over_roof(north_m, east_m, t_s) else 0.0

    def episode_start(self, rng: np.random.Generator, t_s: float) -> np.ndarray:
        """A random x,y within +-start_xy_range_m of the pad, at the fixed start height."""
        pad = self.pad_ned(t_s)
        r = self.cfg.start_xy_range_m
        dn, de = rng.uniform(-r, r, size=2)
        return np.array([pad[0] + dn, pad[1] + de, pad[2] - self.cfg.start_height_above_pad_m])

    def judge(self, ned: np.ndarray, speed_m_s: float, t_s: float) -> Touchdown:
        """Touchdown at ``ned``: on the pad's roof within success_radius_m is a success."""
        pad = self.pad_ned(t_s)
        dist = float(np.hypot(ned[0] - pad[0], ned[1] - pad[1]))
        on_roof = self.over_roof(float(ned[0]), float(ned[1]), t_s) and ned[2] < -0.5 * self.roof_height_m
        return Touchdown(
            ned=(float(ned[0]), float(ned[1]), float(ned[2])),
            speed_m_s=float(speed_m_s),
            distance_to_pad_m=dist,
            on_pad=bool(on_roof and dist <= self.cfg.pad_radius_m),
            success=bool(on_roof and dist <= self.cfg.success_radius_m),
            time_s=t_s,
        )
