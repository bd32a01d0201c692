"""Positions relative to home: the frame in which the companion judges heights and distances.

A real autopilot's local NED origin is where its estimator started, not the ground under home:
real PX4 SIH read between -1.0 and +1.3 m of height while standing on the ground, and the z of
its HOME_POSITION jumped by up to 2 m from one message to the next while the vehicle hovered
(its local z stayed within 0.3 m of one ground level over a whole session). So every height the
companion uses (the geofence, the take-off threshold, the start point above the pad, the
observation the policy sees, the touchdown distance) is taken from a :class:`HomeFrame`:

- north and east: the vehicle's local frame as it is (the pad's position, ``pad_ned_m``, is given
  in it; on a real vehicle its origin is where the estimator started, within metres of home);
- down: the ground under the vehicle the last time it stood there, disarmed (its landed state
  ON_GROUND), else the median of the HOME_POSITION z heard. Between landings PX4 SIH's ground level moved
  by 0.3-0.6 m (over a flight its height estimate drifts); a standing place more than
  ``GROUND_DRIFT_M`` from the known ground is a raised surface (the pad's vehicle), not ground.

Setpoints go back to the vehicle in its own frame (:meth:`HomeFrame.to_vehicle`). A vehicle that
sends no HOME_POSITION and is never seen standing keeps the local origin as home, with no
arithmetic at all, so a vehicle whose home is the origin (our SITL in its experiments, which
starts every episode in the air) gives bit-identical positions.
"""

from __future__ import annotations

import statistics
from collections import deque
from collections.abc import Sequence

from companion.msg.snapshot import Vec3, VehicleSnapshot

GROUND_SAMPLES = 50  # the ground level is the median of this many positions while standing
GROUND_DRIFT_M = 1.0  # PX4 SIH's ground level moved 0.3-0.6 m between landings; a roof is higher


class HomeFrame:
    """Home for one session (its ground level; north/east are the local frame's): :meth:`update`
    with every snapshot, then ask for relative positions."""

    def __init__(self) -> None:
        self._home_down: float | None = None  # median of the HOME_POSITION z heard (PX4 SIH's jump by +-1 m)
        self._home_downs: deque[float] = deque(maxlen=GROUND_SAMPLES)
        self._last_home_down: float | None = None
        self._ground_down: float | None = None  # the accepted ground level, vehicle frame
        self._standing: deque[float] = deque(maxlen=GROUND_SAMPLES)  # this standing period's downs
        self._was_standing = False
        self._origin: Vec3 | None = None

    @property
    def origin(self) -> Vec3 | None:
        """Home in the vehicle's local frame (None: the local origin itself)."""
        return self._origin

    @property
    def source(self) -> str:
        if self._origin is None:
            return "local origin (no HOME_POSITION, never seen standing)"
        down = "the ground it stood on" if self._ground_down is not None else "HOME_POSITION's z (median)"
        return f"north/east: the local frame; down from {down}"

    def update(self, snap: VehicleSnapshot) -> None:
        if snap.home_ned_m is not None and snap.home_ned_m[2] != self._last_home_down:
            self._last_home_down = snap.home_ned_m[2]  # each new message once: the snapshot keeps the last
            self._home_downs.append(snap.home_ned_m[2])
            self._home_down = statistics.median(self._home_downs)
        standing = snap.landed_state == "ON_GROUND" and not snap.armed and snap.position_valid
        if standing:
            if not self._was_standing:
                self._standing.clear()
            self._standing.append(snap.position_ned_m[2])
            self._accept_ground(statistics.median(self._standing))
        self._was_standing = standing
        down = self._ground_down if self._ground_down is not None else self._home_down
        if down is not None:
            self._origin = (0.0, 0.0, down)

    def _accept_ground(self, down_m: float) -> None:
        """The ground level where the vehicle stands now, unless it is far from the known one:
        then it stands on something raised (the pad's vehicle), and the ground stays."""
        known = self._ground_down if self._ground_down is not None else self._home_down
        if known is None or abs(down_m - known) <= GROUND_DRIFT_M:
            self._ground_down = down_m
    def relative(self, snap: VehicleSnapshot) -> Vec3:
        """The vehicle's position (north, east, down) from home, in metres."""
        home = self._origin
        if home is None:
            return snap.position_ned_m
        n, e, d = snap.position_ned_m
        return (n - home[0], e - home[1], d - home[2])

    def height(self, snap: VehicleSnapshot) -> float:
        """Metres above home (positive up)."""
        return -self.relative(snap)[2]

    def to_vehicle(self, relative_ned_m: Sequence[float]) -> Vec3:
        """A point given relative to home, in the vehicle's own local frame (for its setpoints)."""
        n, e, d = (float(v) for v in relative_ned_m)
        home = self._origin
        if home is None:
            return (n, e, d)
        return (n + home[0], e + home[1], d + home[2])
