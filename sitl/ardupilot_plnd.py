"""ArduCopter's precision landing (AC_PrecLand, the PLND_* parameters) in LAND mode.

Pure logic with injected time. After ArduPilot's documentation ("Precision Landing and Loiter")
and its source:

- PLND_ENABLED = 1 and PLND_TYPE = 1 (MAVLink) take LANDING_TARGET: the angles form, or a
  position in MAV_FRAME_BODY_FRD with ``distance`` > 0 (another frame: "Plnd: Frame not
  supported", once). The line of sight is turned into NED with the attitude PLND_LAG ago and
  scaled by ``distance`` (or, without it, by the rangefinder's height);
- PLND_EST_TYPE 0 takes each measurement as it is; 1 (default) filters it per axis (PosVelEKF:
  PLND_ACC_P_NSE, a NIS < 3 gate that gives in after 3 outliers) and uses it only after 2 s of
  measurements no more than 0.5 s apart ("PrecLand: Init Complete"); no measurement for 2 s:
  "PrecLand: Target Lost";
- LAND with the target acquired repositions over it while descending: no descent while it is
  farther than PLD_XY_DIST_MAX; from 2 m down to 0.35 m (with a rangefinder) the descent slows
  with the horizontal error; PLND_OPTIONS bit 0 (moving target) feeds the target's estimated
  velocity forward;
- target lost: PLND_STRICT 0 lands vertically; otherwise, when the sensor should see it (height
  within PLND_ALT_MIN..PLND_ALT_MAX, which needs a rangefinder: without one it never should),
  it keeps descending PLND_TIMEOUT s, then retries from where it last saw the target
  (PLND_RET_BEHAVE 0: the vehicle's place then, 1: the target's) at that height, at most
  PLND_RET_MAX times; then PLND_STRICT 1 lands vertically, 2 hovers.
"""

from __future__ import annotations

import math
from collections import deque
from enum import Enum

from sitl.landing_target import (
    FRAME_BODY_FRD,
    AxisFilter,
    TargetEstimate,
    TargetMeasurement,
    Vec3,
    body_to_ned,
    ray_from_angles,
)
from sitl.px4_precland import Guidance, ParamGetter, VehiclePose

LOST_AFTER_S = 2.0  # LANDING_TARGET_TIMEOUT_MS
INIT_S = 2.0  # EKF_INIT_TIME_MS
INIT_GAP_S = 0.5  # EKF_INIT_SENSOR_MIN_UPDATE_MS
NIS_GATE = 3.0
OUTLIERS_BEFORE_GIVING_IN = 3
SLOW_BELOW_M, SLOW_ABOVE_M = 2.0, 0.35  # the descent slows with the error between these heights
SLOW_ERROR_M = 0.15
MIN_DESCENT_M_S = 0.1
RETRY_REACHED_M = 0.5

PLND_DEFAULTS: dict[str, float] = {  # AC_PrecLand.cpp var_info (copter)
    "PLND_ENABLED": 0, "PLND_TYPE": 0, "PLND_YAW_ALIGN": 0, "PLND_LAND_OFS_X": 0, "PLND_LAND_OFS_Y": 0,
    "PLND_EST_TYPE": 1, "PLND_ACC_P_NSE": 2.5, "PLND_CAM_POS_X": 0.0, "PLND_CAM_POS_Y": 0.0,
    "PLND_CAM_POS_Z": 0.0, "PLND_BUS": -1, "PLND_LAG": 0.02, "PLND_XY_DIST_MAX": 2.5, "PLND_STRICT": 1,
    "PLND_RET_MAX": 4, "PLND_TIMEOUT": 4.0, "PLND_RET_BEHAVE": 0, "PLND_ALT_MIN": 0.75, "PLND_ALT_MAX": 8.0,
    "PLND_OPTIONS": 0, "PLND_ORIENT": 25,
}
REAL_PARAMS = frozenset({"PLND_ACC_P_NSE", "PLND_CAM_POS_X", "PLND_CAM_POS_Y", "PLND_CAM_POS_Z", "PLND_LAG",
                         "PLND_XY_DIST_MAX", "PLND_TIMEOUT", "PLND_ALT_MIN", "PLND_ALT_MAX"})
INT16_PARAMS = frozenset({"PLND_YAW_ALIGN", "PLND_LAND_OFS_X", "PLND_LAND_OFS_Y", "PLND_OPTIONS"})
OPTION_MOVING_TARGET = 1


class ApTargetEstimator:
    """LANDING_TARGET -> the target relative to the vehicle, as AC_PrecLand estimates it."""

    def __init__(self, params: ParamGetter) -> None:
        self._param = params
        self._history: deque[VehiclePose] = deque(maxlen=64)
        self._meas: tuple[Vec3, float] | None = None  # (relative NED, time) not yet used
        self._filters: tuple[AxisFilter, AxisFilter] | None = None
        self._rel: tuple[float, float] = (0.0, 0.0)
        self._rel_vel: tuple[float, float] = (0.0, 0.0)
        self._initialized = False
        self._init_s = -math.inf
        self._last_update_s = -math.inf
        self._outliers = 0
        self._wrong_frame_said = False
        self.acquired = False
        self.events: list[str] = []

    def _delayed(self, t_s: float) -> VehiclePose | None:
        """The vehicle as it was PLND_LAG ago (the inertial history)."""
        lag = min(max(self._param("PLND_LAG"), 0.02), 0.25)
        older = [p for p in self._history if p.time_s <= t_s - lag]
        return older[-1] if older else (self._history[0] if self._history else None)

    def measure(self, m: TargetMeasurement, height_agl_m: float | None) -> bool:
        """One message; False when ArduPilot drops it (as it does: silently, but for the first
        message in a wrong frame)."""
        if m.position_valid:
            if m.frame != FRAME_BODY_FRD:
                if not self._wrong_frame_said:
                    self._wrong_frame_said = True
                    self.events.append("Plnd: Frame not supported")
                return False
            if m.distance_m <= 0:
                return False
            los = (m.x_m / m.distance_m, m.y_m / m.distance_m, m.z_m / m.distance_m)
        else:
            ray = ray_from_angles(m.angle_x_rad, m.angle_y_rad)
            norm = math.sqrt(sum(c * c for c in ray))
            los = (ray[0] / norm, ray[1] / norm, ray[2] / norm)
        delayed = self._delayed(m.time_s)
        if delayed is None or los[2] <= 0:
            return False  # no attitude yet, or a target above the camera: not used
        ned = body_to_ned(los, delayed.attitude_rad)
        if m.distance_m > 0:
            rel = (ned[0] * m.distance_m, ned[1] * m.distance_m, ned[2] * m.distance_m)
        elif height_agl_m is not None and height_agl_m > 0 and ned[2] > 0:
            scale = height_agl_m / ned[2]
            rel = (ned[0] * scale, ned[1] * scale, height_agl_m)
        else:
            return False  # neither a distance nor a rangefinder: ArduPilot cannot place it
        self._meas = (rel, m.time_s)
        return True

    def update(self, pose: VehiclePose) -> None:
        """One cycle: history, prediction, the waiting measurement, init and loss checks."""
        prev = self._history[-1] if self._history else None
        self._history.append(pose)
        if int(self._param("PLND_EST_TYPE")) == 0:
            self._raw(pose, prev)
        else:
            self._kalman(pose, prev)
        if self.acquired and pose.time_s - self._last_update_s > LOST_AFTER_S:
            self.events.append("PrecLand: Target Lost")
            self.acquired = self._initialized = False
            self._filters = None

    def _raw(self, pose: VehiclePose, prev: VehiclePose | None) -> None:
        if self.acquired and prev is not None:
            dt = pose.time_s - prev.time_s
            self._rel = (self._rel[0] - pose.velocity_ned_m_s[0] * dt, self._rel[1] - pose.velocity_ned_m_s[1] * dt)
        if self._meas is not None:
            (rel, t_s), self._meas = self._meas, None
            self._rel = self._from_delayed(rel, t_s, pose)
            self._rel_vel = (-pose.velocity_ned_m_s[0], -pose.velocity_ned_m_s[1])
            if not self._initialized:
                self.events.append("PrecLand: Target Found")
                self._initialized = True
            self._last_update_s, self.acquired = pose.time_s, True

    def _from_delayed(self, rel: Vec3, t_s: float, pose: VehiclePose) -> tuple[float, float]:
        """A relative position measured against the delayed vehicle, brought to now (the output
        prediction: minus how far the vehicle moved since)."""
        delayed = self._delayed(t_s) or pose
        return (rel[0] - (pose.position_ned_m[0] - delayed.position_ned_m[0]),
                rel[1] - (pose.position_ned_m[1] - delayed.position_ned_m[1]))

    def _kalman(self, pose: VehiclePose, prev: VehiclePose | None) -> None:
        if self._filters is not None and prev is not None:
            dt = pose.time_s - prev.time_s
            if dt > 0:
                var = self._param("PLND_ACC_P_NSE") ** 2
                for i, f in enumerate(self._filters):
                    f.predict(dt, -(pose.velocity_ned_m_s[i] - prev.velocity_ned_m_s[i]) / dt, var)
        if self._meas is not None:
            (rel, t_s), self._meas = self._meas, None
            self._fuse(self._from_delayed(rel, t_s, pose), rel[2], pose)
        if not self.acquired and self._initialized:
            if pose.time_s - self._last_update_s > INIT_GAP_S:
                self._initialized, self._filters = False, None
                self.events.append("PrecLand: Init Failed")
            elif pose.time_s - self._init_s > INIT_S:
                self.acquired = True
                self.events.append("PrecLand: Init Complete")
        if self._filters is not None:
            fx, fy = self._filters
            self._rel, self._rel_vel = (fx.x[0], fy.x[0]), (fx.x[1], fy.x[1])

    def _fuse(self, rel: tuple[float, float], height_m: float, pose: VehiclePose) -> None:
        var = (height_m * 0.01 + 0.02) ** 2
        if not self._initialized or self._filters is None:
            self.events.append("PrecLand: Target Found")
            v = pose.velocity_ned_m_s
            self._filters = (AxisFilter(rel[0], -v[0], var, 4.0), AxisFilter(rel[1], -v[1], var, 4.0))
            self._initialized, self._init_s, self._last_update_s = True, pose.time_s, pose.time_s
            return
        if max(f.nis(r, var) for f, r in zip(self._filters, rel)) < NIS_GATE or self._outliers >= OUTLIERS_BEFORE_GIVING_IN:
            self._outliers = 0
            for f, r in zip(self._filters, rel):
                f.fuse(r, var)
            self._last_update_s = pose.time_s
        else:
            self._outliers += 1

    def estimate(self, pose: VehiclePose) -> TargetEstimate | None:
        """The target in the local frame while acquired (its velocity only with the moving-target
        option and the Kalman filter, as ArduPilot's get_target_velocity)."""
        if not self.acquired:
            return None
        n, e, d = pose.position_ned_m
        moving = int(self._param("PLND_OPTIONS")) & OPTION_MOVING_TARGET and int(self._param("PLND_EST_TYPE")) == 1
        vn, ve = (self._rel_vel[0] + pose.velocity_ned_m_s[0], self._rel_vel[1] + pose.velocity_ned_m_s[1]) if moving else (0.0, 0.0)
        return TargetEstimate(self._last_update_s, n + self._rel[0], e + self._rel[1], d + pose.height_agl_m, vn, ve)


class ApState(Enum):
    PRECISION = "precision landing"
    DESCEND_LOST = "target lost: descending"
    RETRY = "retrying"
    VERTICAL = "landing vertically"
    HOVER = "failsafe: hover"


class ApPrecLand:
    """LAND's horizontal and vertical control with precision landing, and the retry state machine."""

    def __init__(self, params: ParamGetter, rangefinder: bool) -> None:
        self._param = params
        self.rangefinder = rangefinder
        self.state = ApState.VERTICAL
        self.retries = 0
        self.events: list[str] = []
        self._point = (0.0, 0.0, 0.0)  # where it lands vertically / hovers / retries to
        self._seen: tuple[Vec3, TargetEstimate] | None = None  # the vehicle and the target when last seen
        self._lost_s = 0.0

    def start(self, pose: VehiclePose) -> None:
        self.state, self.retries, self._seen = ApState.VERTICAL, 0, None
        self._point = pose.position_ned_m

    def _sensor_in_range(self, height_m: float) -> bool:
        lo, hi = self._param("PLND_ALT_MIN"), self._param("PLND_ALT_MAX")
        if lo == 0 and hi == 0:
            return True
        if not self.rangefinder:
            return False
        return not ((hi > 0 and height_m > hi) or (lo > 0 and height_m < lo))

    def update(self, pose: VehiclePose, target: TargetEstimate | None, land_speed_m_s: float) -> Guidance:
        if target is not None:
            return self._precise(pose, target, land_speed_m_s)
        if self.state is ApState.PRECISION:
            self._on_loss(pose)
        if self.state is ApState.DESCEND_LOST and pose.time_s - self._lost_s > self._param("PLND_TIMEOUT"):
            self._retry_or_give_up(pose)
        if self.state is ApState.RETRY:
            self._check_retry(pose)
        n, e, d = self._point
        if self.state is ApState.DESCEND_LOST:
            n, e, _ = pose.position_ned_m
        return Guidance(n, e, d if self.state in (ApState.RETRY, ApState.HOVER) else None, self.state.value)

    def _precise(self, pose: VehiclePose, target: TargetEstimate, land_speed_m_s: float) -> Guidance:
        n, e, d = pose.position_ned_m
        self.state = ApState.PRECISION
        self._seen = (pose.position_ned_m, target)
        error = math.hypot(target.north_m - n, target.east_m - e)
        max_error = self._param("PLND_XY_DIST_MAX")
        if max_error > 0 and error > max_error:
            return Guidance(target.north_m, target.east_m, d, self.state.value, target.vn_m_s, target.ve_m_s)
        descent = land_speed_m_s
        if self.rangefinder and SLOW_ABOVE_M < pose.height_agl_m < SLOW_BELOW_M:
            half = 0.5 * land_speed_m_s
            descent = max(MIN_DESCENT_M_S, half - error * half / SLOW_ERROR_M)
        return Guidance(target.north_m, target.east_m, None, self.state.value, target.vn_m_s, target.ve_m_s, descent)

    def _on_loss(self, pose: VehiclePose) -> None:
        if int(self._param("PLND_STRICT")) == 0 or not self._sensor_in_range(pose.height_agl_m):
            self.state, self._point = ApState.VERTICAL, pose.position_ned_m
            return
        self.state, self._lost_s = ApState.DESCEND_LOST, pose.time_s

    def _retry_or_give_up(self, pose: VehiclePose) -> None:
        if self.retries < int(self._param("PLND_RET_MAX")) and self._seen is not None:
            vehicle, target = self._seen
            self.retries += 1
            self.events.append(f"PrecLand: Retrying landing ({self.retries})")
            at_target = int(self._param("PLND_RET_BEHAVE")) == 1
            self._point = (target.north_m, target.east_m, vehicle[2]) if at_target else vehicle
            self.state = ApState.RETRY
            return
        strict = int(self._param("PLND_STRICT"))
        self.events.append("PrecLand: Target not found, " + ("hovering" if strict == 2 else "landing vertically"))
        self.state = ApState.HOVER if strict == 2 else ApState.VERTICAL
        self._point = pose.position_ned_m

    def _check_retry(self, pose: VehiclePose) -> None:
        """At the retry point without the target: descend and look again."""
        if math.dist(pose.position_ned_m, self._point) < RETRY_REACHED_M:
            self.state, self._lost_s = ApState.DESCEND_LOST, pose.time_s
