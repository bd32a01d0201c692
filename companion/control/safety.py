"""Safety checks of the companion: a geofence, and limits applied last to every setpoint.

The session asks the fence each tick and holds the vehicle when it says "outside"; the
limiter sits between whatever produced a setpoint (joystick mapping, hold, go-to) and the
link, so its limits hold whatever happened upstream. The vehicle's own failsafes cover a
dead companion.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from companion.config import CommandsConfig, SafetyConfig
from companion.msg.setpoint import VelocitySetpoint


@dataclass(frozen=True)
class FenceStatus:
    """Whether a position is inside the fence and, if not, why (for the operator and the log)."""

    inside: bool
    reason: str | None = None

    def __post_init__(self) -> None:
        if self.inside == (self.reason is not None):
            raise ValueError("a FenceStatus has a reason exactly when it is outside")


class Geofence:
    """A vertical cylinder: horizontal radius around a centre and an altitude band above home.

    Altitude is ``-z`` of the local NED frame (whose origin is on the ground below home).
    """

    def __init__(
        self,
        radius_m: float,
        min_alt_m: float,
        max_alt_m: float,
        centre_ne_m: tuple[float, float] = (0.0, 0.0),
    ) -> None:
        if not (radius_m > 0 and min_alt_m < max_alt_m):
            raise ValueError(
                f"fence needs radius > 0 and min_alt < max_alt, got radius {radius_m}, "
                f"altitudes [{min_alt_m}, {max_alt_m}]"
            )
        self.radius_m, self.min_alt_m, self.max_alt_m = radius_m, min_alt_m, max_alt_m
        self.centre_ne_m = (float(centre_ne_m[0]), float(centre_ne_m[1]))

    @classmethod
    def from_config(
        cls, cfg: SafetyConfig, centre_ne_m: tuple[float, float] = (0.0, 0.0)
    ) -> Geofence:
        """The fence of ``[companion.safety]`` around ``centre_ne_m`` (e.g. the session's start)."""
        return cls(cfg.fence_radius_m, cfg.fence_min_alt_m, cfg.fence_max_alt_m, centre_ne_m)

    def check(self, position_ned_m: Sequence[float], standing: bool = False) -> FenceStatus:
        """``standing``: the vehicle stands on a surface (the touchdown assist's evidence); then
        the floor is not checked: standing is not flying below home, and a drifting height
        estimate (PX4 SIH: 1.4 m) must not stop a touchdown."""
        n, e, d = (float(v) for v in position_ned_m)
        if not all(math.isfinite(v) for v in (n, e, d)):
            return FenceStatus(False, "position unknown (non-finite estimate)")
        distance_m = math.hypot(n - self.centre_ne_m[0], e - self.centre_ne_m[1])
        if distance_m > self.radius_m:
            return FenceStatus(
                False, f"{distance_m:.1f} m from the centre, fence radius {self.radius_m:g} m"
            )
        alt_m = -d
        if alt_m > self.max_alt_m:
            return FenceStatus(
                False, f"altitude {alt_m:.1f} m above the fence's {self.max_alt_m:g} m"
            )
        if alt_m < self.min_alt_m and not standing:
            return FenceStatus(
                False, f"altitude {alt_m:.1f} m below the fence's {self.min_alt_m:g} m"
            )
        return FenceStatus(True)


class SetpointLimiter:
    """Clip each axis to the commands' limits, then (optionally) limit its rate of change.

    Rate limits are accelerations from ``[companion.safety]``; 0 disables an axis' limit.
    The limiter remembers the last setpoint it let through; :meth:`reset` forgets it (e.g.
    after a hold), so the next one starts from what is asked.
    """

    def __init__(self, commands: CommandsConfig, safety: SafetyConfig) -> None:
        self._max = np.array(
            [
                commands.v_xy_max_m_s,
                commands.v_xy_max_m_s,
                commands.v_z_max_m_s,
                commands.yaw_rate_max_rad_s,
            ]
        )
        rates = [
            safety.max_accel_xy_m_s2,
            safety.max_accel_xy_m_s2,
            safety.max_accel_z_m_s2,
            safety.max_yaw_accel_rad_s2,
        ]
        self._max_rate = np.array([r if r > 0 else np.inf for r in rates])
        self._last: np.ndarray | None = None
        self.limited_count = 0

    def reset(self) -> None:
        self._last = None

    @property
    def max_down_m_s(self) -> float:
        """The fastest descent it lets through (the commands' v_z_max)."""
        return float(self._max[2])

    def apply(self, setpoint: VelocitySetpoint, dt_s: float) -> VelocitySetpoint:
        """The setpoint to send after ``dt_s`` seconds since the previous one."""
        wanted = np.array(setpoint.as_tuple())
        out = self.clipped(wanted)
        if self._last is not None and dt_s > 0:
            out = self.rate_limited(out, self._last, dt_s)
        self.limited_count += int(np.count_nonzero(out != wanted))
        self._last = out
        return VelocitySetpoint(*(float(v) for v in out))

    def clipped(self, wanted: np.ndarray) -> np.ndarray:
        """Setpoints ``(..., 4)`` (forward, right, down, yaw rate) clipped to the commands'
        limits, element by element (a stack of them as each alone); no state."""
        return np.clip(wanted, -self._max, self._max)

    def rate_limited(self, out: np.ndarray, last: np.ndarray, dt_s: float) -> np.ndarray:
        """``out`` moved at most one acceleration step of ``dt_s`` from ``last``, element by
        element; no state."""
        step = self._max_rate * dt_s
        return np.clip(out, last - step, last + step)
