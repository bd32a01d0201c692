"""The frame JSBSim flies in when the ground vehicle's roof carries the multirotor
(``[sitl.world] roof_carries``; docs/sitl.md "The world").

JSBSim's ground is static: its legs' friction acts on the velocity over that ground, and a
vehicle standing still on it stays where it is. To make the driving roof as solid as the ground
the dynamics let JSBSim fly in the frame of the surface below the multirotor: the ground's (the
world's) or, while the roof is below it, the roof's. In the roof's frame the roof is JSBSim's
static ground, so the friction at touchdown acts on the velocity relative to the roof and a
multirotor standing on it is carried along. The world state is JSBSim's plus the frame's
``offset_ne`` (its displacement) and ``velocity_ne``; the air JSBSim sees is the world's wind
minus the frame's velocity; when the frame's velocity changes (the roof turns or changes speed,
or the frame switches between ground and roof) the dynamics apply the force of that non-inertial
frame, -mass x its acceleration. The roof frame only translates: the box keeps its long side
along north (sitl/world.py), so there are no rotational frame forces.

Why a frame rather than carrying a vehicle that rests (JSBSim's position can be written
mid-run, its velocity cannot): the touchdown itself would still meet still ground, braked from
the pad's speed. Why frames that switch rather than the roof's frame throughout: in the roof's
frame the open ground would move under a multirotor standing on it (one that boots beside the
ground vehicle would slide across the world at the roof's speed). Switching happens only where
the surface below changes, which is in flight (the surface drops or rises under the vehicle); a
multirotor that slides off the roof's edge falls, and its world velocity is kept through the
switch.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np


class Carrier(Protocol):
    """The moving surface the dynamics may fly in the frame of (:class:`sitl.world.World`)."""

    @property
    def roof_height_m(self) -> float: ...

    def over_roof(self, north_m: float, east_m: float, t_s: float) -> bool: ...

    def position_ne(self, t_s: float) -> np.ndarray: ...

    def velocity_at(self, t_s: float) -> np.ndarray: ...


@dataclass(frozen=True)
class _Offset:
    """World minus JSBSim position: ``base_ne`` plus, in the roof's frame, the roof's
    displacement since it was at ``roof_ne``."""

    on_roof: bool
    base_ne: tuple[float, float] = (0.0, 0.0)
    roof_ne: tuple[float, float] = (0.0, 0.0)

    def at(self, carrier: Carrier, t_s: float) -> tuple[float, float]:
        n0, e0 = self.base_ne
        if not self.on_roof:
            return n0, e0
        n, e = carrier.position_ne(t_s)
        rn, re = self.roof_ne
        return n0 + (float(n) - rn), e0 + (float(e) - re)


class RoofFrame:
    """Which frame JSBSim's state is in (the ground's or the roof's) and where that frame is.

    ``offset_ne`` is the world position minus JSBSim's: zero at the last :meth:`start`, then the
    roof's displacement while in its frame (in closed form: a multirotor standing on the roof
    stays on the same spot of it, however long and through any turns), constant on the ground.
    ``velocity_ne`` is the frame velocity JSBSim's velocity is relative to now (the dynamics
    keep it as their frame force changes JSBSim's velocity).
    """

    def __init__(self, carrier: Carrier) -> None:
        self.carrier = carrier
        self.on_roof = False
        self.velocity_ne = (0.0, 0.0)
        self._offset = _Offset(False)
        self._before = self._offset  # the offset before ``_offset_from_s`` (a switch's lag)
        self._offset_from_s = -math.inf

    def start(self, on_roof: bool, t_s: float) -> None:
        """A reset at ``t_s``: JSBSim's position is the world's, in the frame of the surface below."""
        self.on_roof = on_roof
        self._offset = self._before = self._anchored(on_roof, (0.0, 0.0), t_s)
        self._offset_from_s = -math.inf
        self.velocity_ne = self.velocity_at(t_s)

    def switch(self, on_roof: bool, t_s: float, lag_s: float) -> None:
        """Ground to roof or back: the frame's velocity is the new one's from ``t_s`` on (the
        dynamics' frame force changes JSBSim's velocity over the step from then), its offset
        from ``lag_s`` later, continuous. Why later: JSBSim integrates its position with the
        trapezoid of the two velocities before (its ``position/translational`` integrator), so
        its position takes a change of velocity up that late; the world position of a flying
        vehicle then stays what it would be without the switch.
        """
        from_s = t_s + lag_s
        self._before = self._offset
        self._offset = self._anchored(on_roof, self._offset.at(self.carrier, from_s), from_s)
        self._offset_from_s = from_s
        self.on_roof = on_roof

    def _anchored(self, on_roof: bool, base_ne: tuple[float, float], t_s: float) -> _Offset:
        if not on_roof:
            return _Offset(False, base_ne)
        n, e = self.carrier.position_ne(t_s)
        return _Offset(True, base_ne, (float(n), float(e)))

    def offset_ne(self, t_s: float) -> tuple[float, float]:
        """World position minus JSBSim's position at ``t_s``."""
        offset = self._offset if t_s >= self._offset_from_s else self._before
        return offset.at(self.carrier, t_s)

    def velocity_at(self, t_s: float) -> tuple[float, float]:
        """The frame's velocity at ``t_s`` (the roof's, or zero on the ground)."""
        if not self.on_roof:
            return 0.0, 0.0
        n, e = self.carrier.velocity_at(t_s)
        return float(n), float(e)


def ned_to_body(vector_ned: tuple[float, float, float], attitude_rad: tuple[float, float, float]
                ) -> tuple[float, float, float]:
    """A NED vector in the body's forward-right-down axes at roll, pitch, yaw (ZYX Euler)."""
    n, e, d = vector_ned
    roll, pitch, yaw = attitude_rad
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    x = cp * cy * n + cp * sy * e - sp * d
    y = (sr * sp * cy - cr * sy) * n + (sr * sp * sy + cr * cy) * e + sr * cp * d
    z = (cr * sp * cy + sr * sy) * n + (cr * sp * sy - sr * cy) * e + cr * cp * d
    return x, y, z
