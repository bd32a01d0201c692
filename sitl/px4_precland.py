"""PX4's precision landing (navigator ``precland``) and its landing target estimator (``LTEST``).

Pure logic with injected time: :class:`Px4TargetEstimator` turns LANDING_TARGET into a target
estimate; :class:`Px4PrecLand` is the mode's state machine, returning a :class:`Guidance` that
the vehicle flies. After PX4's documentation ("Precision Landing") and its source:

- a LANDING_TARGET with a position in MAV_FRAME_LOCAL_NED is the target's place itself, taken as
  it is (PX4's receiver publishes it without filtering); another frame is refused with
  "Landing target: coordinate frame N unsupported";
- the angles form goes through the landing target estimator: the ray is scaled to the height
  above ground and filtered per axis (a position/velocity Kalman filter driven by the vehicle's
  acceleration, LTEST_ACC_UNC, LTEST_MEAS_UNC x height^2, LTEST_POS_UNC_IN, LTEST_VEL_UNC_IN,
  3-sigma gate); no measurement for 2 s resets it. LTEST_MODE 1 (stationary) makes PX4 also
  feed the target's apparent velocity to its own position estimator as the vehicle's; the SITL
  has no estimator of that kind to bias, so here it means what it assumes: the target does
  not move (relative velocity = minus the vehicle's), and a moving pad shows as lag;
- the phases (PX4 main, 2026: the navigator's precland, whose console log says "Precland:
  switching to ..."; none of it is sent as STATUSTEXT): start -> horizontal approach (at the
  altitude it started, to the target's place, speed and acceleration limited) -> descent above
  the target once within PLD_HACC_RAD on both axes (2 s after it first was) -> final approach
  below PLD_FAPPR_ALT over the target, where losing it no longer matters. There is no time
  limit on the approach: a target it cannot get within PLD_HACC_RAD of (a pad driving away
  faster than the position loop follows) keeps it approaching at altitude. Target not seen for
  PLD_BTOUT: stop at the current altitude over its last place, back to start (counted); at the
  start point without the target for 1 s: search (climb to PLD_SRCH_ALT above the local origin)
  for PLD_SRCH_TOUT; more than PLD_MAX_SRCH starts or a search timeout: fallback, a normal
  landing at the target's last place. Opportunistic (NAV_LAND in a mission, param2 = 1) falls
  back at once when no target is seen at the start.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum

from sitl.landing_target import (
    FRAME_LOCAL_NED,
    AxisFilter,
    LandingTargetRejected,
    TargetEstimate,
    TargetMeasurement,
    Vec3,
    relative_from_ray,
)

ParamGetter = Callable[[str], float]
ESTIMATOR_TIMEOUT_S = 2.0  # PX4's landing_target_estimator: no measurement this long -> reset
GATE_NIS = 9.0  # a 3-sigma innovation gate
DESCEND_AFTER_S = 2.0  # within PLD_HACC_RAD (first) this long before descending
START_SEARCH_AFTER_S = 1.0  # at the start point without a target this long: search
SEARCH_SETTLE_S = 1.0  # target seen while searching: settle this long before approaching
ACCEPTANCE_RADIUS_M = 2.0  # the navigator's acceptance radius for "at the start point"
FINAL_LOST_S = 0.5  # close to the ground a target older than this counts as lost

PX4_PRECLAND_DEFAULTS: dict[str, float] = {  # PX4's precland_params.c
    "PLD_BTOUT": 5.0, "PLD_HACC_RAD": 0.2, "PLD_FAPPR_ALT": 0.1, "PLD_SRCH_ALT": 10.0,
    "PLD_SRCH_TOUT": 10.0, "PLD_MAX_SRCH": 3,
}
PX4_LTEST_DEFAULTS: dict[str, float] = {  # PX4's landing_target_estimator_params.c
    "LTEST_MODE": 0, "LTEST_ACC_UNC": 10.0, "LTEST_MEAS_UNC": 0.005, "LTEST_POS_UNC_IN": 0.1,
    "LTEST_VEL_UNC_IN": 0.1, "LTEST_SCALE_X": 1.0, "LTEST_SCALE_Y": 1.0, "LTEST_SENS_ROT": 2,
    "LTEST_SENS_POS_X": 0.0, "LTEST_SENS_POS_Y": 0.0, "LTEST_SENS_POS_Z": 0.0,
}
INT_PARAMS = frozenset({"PLD_MAX_SRCH", "LTEST_MODE", "LTEST_SENS_ROT"})


@dataclass(frozen=True)
class VehiclePose:
    """What the autopilot knows of itself: its local (reported) frame, height above ground."""

    time_s: float
    position_ned_m: Vec3
    velocity_ned_m_s: Vec3
    attitude_rad: Vec3
    height_agl_m: float


class Px4TargetEstimator:
    """LANDING_TARGET -> the target's place in the local frame, as PX4 gets it."""

    def __init__(self, params: ParamGetter) -> None:
        self._param = params
        self._filters: tuple[AxisFilter, AxisFilter] | None = None
        self._last_fused_s = -math.inf
        self._last_predict_s = -math.inf
        self._last_velocity: Vec3 | None = None
        self.estimate: TargetEstimate | None = None
        self.updated = False  # a new estimate since the state machine last looked

    @property
    def active(self) -> bool:
        """A filter is running (and needs predicting)."""
        return self._filters is not None

    def measure(self, m: TargetMeasurement, pose: VehiclePose) -> None:
        """One message; raises LandingTargetRejected for a frame PX4 does not take."""
        if m.position_valid:
            if m.frame != FRAME_LOCAL_NED:
                raise LandingTargetRejected(f"Landing target: coordinate frame {m.frame} unsupported")
            self._publish(TargetEstimate(m.time_s, m.x_m, m.y_m, m.z_m))
            return
        rel = relative_from_ray(self._body_ray(m), pose.attitude_rad, pose.height_agl_m)
        if rel is not None and pose.height_agl_m > 0:
            self._fuse(rel, pose, m.time_s)

    def _body_ray(self, m: TargetMeasurement) -> Vec3:
        """The sensor's ray (angles taken as tangents, scaled by LTEST_SCALE_X/Y) turned into the
        body frame by LTEST_SENS_ROT (yaw in 45 deg steps; the default 2, yaw 90, is a camera
        whose image x points right: :func:`ray_from_angles` with tangent=False)."""
        sx, sy = m.angle_x_rad * self._param("LTEST_SCALE_X"), m.angle_y_rad * self._param("LTEST_SCALE_Y")
        yaw = math.radians(45.0 * int(self._param("LTEST_SENS_ROT")))
        c, s = math.cos(yaw), math.sin(yaw)
        return (c * sx - s * sy, s * sx + c * sy, 1.0)

    def predict(self, pose: VehiclePose) -> None:
        """Advance the filter to ``pose.time_s`` with the vehicle's acceleration (from its velocity)."""
        v = pose.velocity_ned_m_s
        if self._filters is not None and pose.time_s - self._last_fused_s > ESTIMATOR_TIMEOUT_S:
            self._filters = None  # PX4 warns "Timeout" and starts afresh on the next measurement
        if self._filters is not None and self._last_velocity is not None:
            dt = pose.time_s - self._last_predict_s
            if dt > 0:
                acc_var = self._param("LTEST_ACC_UNC")
                for i, f in enumerate(self._filters):
                    f.predict(dt, -(v[i] - self._last_velocity[i]) / dt, acc_var)
                    if self._stationary():
                        f.pin_velocity(-v[i])
        self._last_velocity, self._last_predict_s = v, pose.time_s

    def _stationary(self) -> bool:
        return int(self._param("LTEST_MODE")) == 1

    def _fuse(self, rel: Vec3, pose: VehiclePose, t_s: float) -> None:
        v = pose.velocity_ned_m_s
        if self._filters is None:
            pos_var, vel_var = self._param("LTEST_POS_UNC_IN"), self._param("LTEST_VEL_UNC_IN")
            self._filters = (AxisFilter(rel[0], -v[0], pos_var, vel_var), AxisFilter(rel[1], -v[1], pos_var, vel_var))
            self._last_velocity, self._last_predict_s = v, pose.time_s
        else:
            var = self._param("LTEST_MEAS_UNC") * pose.height_agl_m ** 2
            if any(f.nis(r, var) > GATE_NIS for f, r in zip(self._filters, rel)):
                return  # "Landing target measurement rejected"
            for f, r in zip(self._filters, rel):
                f.fuse(r, var)
        self._last_fused_s = t_s
        fx, fy = self._filters
        n, e, d = pose.position_ned_m
        self._publish(TargetEstimate(t_s, n + fx.x[0], e + fy.x[0], d + rel[2],
                                     fx.x[1] + v[0], fy.x[1] + v[1]))

    def _publish(self, estimate: TargetEstimate) -> None:
        self.estimate = estimate
        self.updated = True

    def take(self) -> tuple[TargetEstimate | None, bool]:
        """The latest estimate and whether it is new since the last call."""
        updated, self.updated = self.updated, False
        return self.estimate, updated


class Px4State(Enum):
    START = "start"
    HORIZONTAL_APPROACH = "horizontal approach"
    DESCEND_ABOVE_TARGET = "descend above target"
    FINAL_APPROACH = "final approach"
    SEARCH = "search"
    FALLBACK = "fallback"
    DONE = "done"


class PrecLandMode(Enum):
    """MAV_CMD_NAV_LAND param2 (PRECISION_LAND_MODE); the mode AUTO.PRECLAND is always required."""

    OPPORTUNISTIC = 1
    REQUIRED = 2


@dataclass(frozen=True)
class Guidance:
    """What to fly now: to (north, east); hold ``down_m`` or, when None, descend at land speed.
    ``vn/ve`` feed forward the target's velocity (ArduPilot's moving-target option)."""

    north_m: float
    east_m: float
    down_m: float | None
    state: str
    vn_m_s: float = 0.0
    ve_m_s: float = 0.0
    descent_m_s: float | None = None  # None: the land speed

    @property
    def descending(self) -> bool:
        return self.down_m is None


@dataclass
class _Slew:
    """PX4's precland slew rate: the approach setpoint moves at most at cruise speed, accelerates
    at most MPC_ACC_HOR and slows so it can stop at the target."""

    north_m: float
    east_m: float
    vn_m_s: float = 0.0
    ve_m_s: float = 0.0

    def step(self, goal_n: float, goal_e: float, dt_s: float, cruise_m_s: float, acc_m_s2: float) -> tuple[float, float]:
        dn, de = goal_n - self.north_m, goal_e - self.east_m
        dist = math.hypot(dn, de)
        if dt_s <= 0 or dist < 1e-9:
            return self.north_m, self.east_m
        speed = min(cruise_m_s, dist / dt_s, math.sqrt(2 * acc_m_s2 * dist))
        want_n, want_e = dn / dist * speed, de / dist * speed
        dvn, dve = want_n - self.vn_m_s, want_e - self.ve_m_s
        dv = math.hypot(dvn, dve)
        if dv > acc_m_s2 * dt_s:
            dvn, dve = dvn / dv * acc_m_s2 * dt_s, dve / dv * acc_m_s2 * dt_s
        self.vn_m_s, self.ve_m_s = self.vn_m_s + dvn, self.ve_m_s + dve
        self.north_m += self.vn_m_s * dt_s
        self.east_m += self.ve_m_s * dt_s
        return self.north_m, self.east_m


@dataclass(frozen=True)
class Px4Limits:
    """The position controller's limits the slew rate uses (PX4: MPC_XY_CRUISE, MPC_ACC_HOR)."""

    cruise_m_s: float = 5.0
    acc_m_s2: float = 3.0


class Px4PrecLand:
    """The precision landing state machine (AUTO.PRECLAND, or a mission's NAV_LAND with param2).

    It steers to the "approximate landing position": where it was when activated, then the
    (slewed) target while it is seen; start, search, lost and fallback all fly to that point."""

    def __init__(self, params: ParamGetter, limits: Px4Limits = Px4Limits()) -> None:
        self._param = params
        self.limits = limits
        self.state = Px4State.DONE
        self.mode = PrecLandMode.REQUIRED
        self.search_count = 0
        self.events: list[str] = []  # what PX4 logs on its console (not sent as STATUSTEXT)
        self._state_since_s = 0.0
        self._reached_s: float | None = None
        self._acquired_s: float | None = None
        self._landing_ne = (0.0, 0.0)  # PX4's _approximate_landing_pos
        self._down_m: float | None = None  # the altitude held (None: where it is)
        self._approach_down_m = 0.0
        self._slew = _Slew(0.0, 0.0)
        self._last_target: TargetEstimate | None = None
        self._last_time_s = 0.0

    # ----- transitions ---------------------------------------------------------------------
    def start(self, pose: VehiclePose, mode: PrecLandMode = PrecLandMode.REQUIRED) -> None:
        """Activation: from where it is, look for the target."""
        self.mode = mode
        self.search_count = 0
        self._last_target = None
        self._landing_ne = (pose.position_ned_m[0], pose.position_ned_m[1])
        self._down_m = pose.position_ned_m[2]
        self._to_start(pose)
        self._last_time_s = pose.time_s

    def _enter(self, state: Px4State, t_s: float) -> None:
        if state is not Px4State.START and state is not self.state:
            self.events.append(f"Precland: switching to {state.value}")
        self.state = state
        self._state_since_s = t_s

    def _to_start(self, pose: VehiclePose) -> None:
        """Back to the start (counted); over PLD_MAX_SRCH of them: fallback."""
        if self.search_count > int(self._param("PLD_MAX_SRCH")):
            self._to_fallback(pose)
            return
        self.search_count += 1
        self._reached_s = None
        self._enter(Px4State.START, pose.time_s)

    def _to_approach(self, pose: VehiclePose) -> None:
        n, e, d = pose.position_ned_m
        self._approach_down_m = d
        self._reached_s = None
        self._slew = _Slew(n, e, pose.velocity_ned_m_s[0], pose.velocity_ned_m_s[1])
        self._enter(Px4State.HORIZONTAL_APPROACH, pose.time_s)

    def _to_search(self, pose: VehiclePose) -> None:
        self.events.append("Climbing to search altitude.")
        self._acquired_s = None
        self._down_m = self._search_down()
        self._enter(Px4State.SEARCH, pose.time_s)

    def _search_down(self) -> float:
        return -self._param("PLD_SRCH_ALT")  # above the local origin (PX4: ref_alt + PLD_SRCH_ALT)

    def _to_fallback(self, pose: VehiclePose) -> None:
        self._enter(Px4State.FALLBACK, pose.time_s)

    def _lost(self, pose: VehiclePose) -> None:
        """Stop at the current altitude over the last place of the target, back to start."""
        self.events.append(f"Lost landing target while landing, state: {self.state.value}")
        self._down_m = pose.position_ned_m[2]
        self._to_start(pose)

    def landed(self, t_s: float) -> None:
        self._enter(Px4State.DONE, t_s)

    # ----- conditions ----------------------------------------------------------------------
    def _valid(self, target: TargetEstimate | None, t_s: float) -> bool:
        return target is not None and t_s - target.time_s <= self._param("PLD_BTOUT")

    def _within(self, target: TargetEstimate, pose: VehiclePose) -> bool:
        r = self._param("PLD_HACC_RAD")
        n, e, _ = pose.position_ned_m
        return abs(target.north_m - n) < r and abs(target.east_m - e) < r

    def _final(self, target: TargetEstimate | None, pose: VehiclePose) -> bool:
        """Closer above the target than PLD_FAPPR_ALT."""
        return (self._valid(target, pose.time_s) and target is not None
                and target.down_m - pose.position_ned_m[2] < self._param("PLD_FAPPR_ALT"))

    # ----- the step --------------------------------------------------------------------------
    def update(self, pose: VehiclePose, target: TargetEstimate | None, updated: bool) -> Guidance:
        """One navigator cycle: the phase's checks, then what to fly."""
        dt = pose.time_s - self._last_time_s
        self._last_time_s = pose.time_s
        if target is not None:
            self._last_target = target
        run = {
            Px4State.START: self._run_start,
            Px4State.HORIZONTAL_APPROACH: self._run_approach,
            Px4State.DESCEND_ABOVE_TARGET: self._run_descend,
            Px4State.SEARCH: self._run_search,
        }.get(self.state)
        if run is not None:
            run(pose, self._last_target, updated)
        return self._guidance(pose, dt)

    def _run_start(self, pose: VehiclePose, target: TargetEstimate | None, updated: bool) -> None:
        if updated and self._valid(target, pose.time_s):
            self._to_approach(pose)
            return
        if self.mode is PrecLandMode.OPPORTUNISTIC:
            self._to_fallback(pose)
            return
        n, e, _ = pose.position_ned_m
        if math.hypot(n - self._landing_ne[0], e - self._landing_ne[1]) < ACCEPTANCE_RADIUS_M:
            self._reached_s = pose.time_s if self._reached_s is None else self._reached_s
            if self._param("PLD_SRCH_TOUT") <= 0:
                self._to_fallback(pose)
            elif pose.time_s - self._reached_s > START_SEARCH_AFTER_S:
                self._to_search(pose)

    def _run_approach(self, pose: VehiclePose, target: TargetEstimate | None, updated: bool) -> None:
        assert target is not None
        near_last = self._within(target, pose)
        if near_last and not self._valid(target, pose.time_s):
            self._lost(pose)  # at the last place it was seen, and it is not there
            return
        if updated and near_last:
            self._reached_s = pose.time_s if self._reached_s is None else self._reached_s
            if pose.time_s - self._reached_s > DESCEND_AFTER_S:
                self._enter(Px4State.DESCEND_ABOVE_TARGET, pose.time_s)

    def _run_descend(self, pose: VehiclePose, target: TargetEstimate | None, updated: bool) -> None:
        final = self._final(target, pose)
        if final:
            keep = target is not None and pose.time_s - target.time_s < FINAL_LOST_S
        else:
            keep = self._valid(target, pose.time_s)
        if keep:
            return
        if final:
            self._enter(Px4State.FINAL_APPROACH, pose.time_s)
        else:
            self._lost(pose)

    def _run_search(self, pose: VehiclePose, target: TargetEstimate | None, updated: bool) -> None:
        seen = updated and self._valid(target, pose.time_s)
        if not seen:
            self._acquired_s, self._down_m = None, self._search_down()
        elif self._acquired_s is None:
            self._acquired_s = pose.time_s  # stop climbing, with a margin of 1 m
            self._down_m = max(self._search_down(), pose.position_ned_m[2] - 1.0)
        if self._acquired_s is not None and pose.time_s - self._acquired_s > SEARCH_SETTLE_S and seen:
            self._to_approach(pose)
            return
        if pose.time_s - self._state_since_s > self._param("PLD_SRCH_TOUT"):
            self.events.append("Search timed out")
            self._to_fallback(pose)

    # ----- output ----------------------------------------------------------------------------
    def _guidance(self, pose: VehiclePose, dt_s: float) -> Guidance:
        state, target = self.state, self._last_target
        if state is Px4State.HORIZONTAL_APPROACH and target is not None:
            self._landing_ne = self._slew.step(target.north_m, target.east_m, dt_s, self.limits.cruise_m_s,
                                               self.limits.acc_m_s2)
            return Guidance(*self._landing_ne, self._approach_down_m, state.value)
        if state is Px4State.DESCEND_ABOVE_TARGET and target is not None:
            self._landing_ne = (target.north_m, target.east_m)
        if state in (Px4State.DESCEND_ABOVE_TARGET, Px4State.FINAL_APPROACH, Px4State.FALLBACK, Px4State.DONE):
            return Guidance(*self._landing_ne, None, state.value)
        down = pose.position_ned_m[2] if self._down_m is None else self._down_m
        return Guidance(*self._landing_ne, down, state.value)
