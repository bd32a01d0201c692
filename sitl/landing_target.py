"""LANDING_TARGET as the autopilots read it, and the filters that turn it into a target estimate.

Pure geometry and filtering with injected time (no I/O), shared by PX4's precision landing
(:mod:`sitl.px4_precland`) and ArduCopter's (:mod:`sitl.ardupilot_plnd`).

The two message forms (MAVLink's landing target protocol):

- angles (``position_valid = 0``): ``angle_x`` / ``angle_y`` are the target's offset from the
  image centre of a downward camera whose image x points right and image y aft, so the ray to
  the target in the body frame (FRD) is ``(-tan angle_y, tan angle_x, 1)`` (ArduPilot's
  AC_PrecLand_MAVLink; PX4's estimator gets the same with LTEST_SENS_ROT = yaw 90, its default);
- a position (``position_valid = 1``): ``x, y, z`` in ``frame``: PX4 takes only MAV_FRAME_LOCAL_NED
  (the target's place in the vehicle's local frame), ArduPilot only MAV_FRAME_BODY_FRD (the
  vector from the vehicle to the target, with ``distance`` its length).

A used field that is not finite makes the whole message invalid: it is refused, never flown.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

FRAME_LOCAL_NED = 1
FRAME_BODY_FRD = 12
Vec3 = tuple[float, float, float]


class LandingTargetRejected(ValueError):
    """A LANDING_TARGET that cannot be used; the reason goes to STATUSTEXT."""


@dataclass(frozen=True)
class TargetMeasurement:
    """One LANDING_TARGET, stamped with the simulation time it arrived at."""

    time_s: float
    angle_x_rad: float
    angle_y_rad: float
    distance_m: float
    frame: int
    position_valid: bool
    x_m: float = 0.0
    y_m: float = 0.0
    z_m: float = 0.0
    size_x_rad: float = 0.0
    size_y_rad: float = 0.0

    def __post_init__(self) -> None:
        used = {"angle_x": self.angle_x_rad, "angle_y": self.angle_y_rad, "distance": self.distance_m,
                "size_x": self.size_x_rad, "size_y": self.size_y_rad}
        if self.position_valid:
            used |= {"x": self.x_m, "y": self.y_m, "z": self.z_m}
        bad = [name for name, value in used.items() if not math.isfinite(value)]
        if bad:
            raise LandingTargetRejected(f"LANDING_TARGET refused: non-finite {', '.join(bad)}")
        if not self.position_valid and max(abs(self.angle_x_rad), abs(self.angle_y_rad)) >= math.pi / 2:
            raise LandingTargetRejected("LANDING_TARGET refused: angle beyond +-90 deg")


def body_to_ned(v: Vec3, attitude_rad: Vec3) -> Vec3:
    """Rotate a body-frame (FRD) vector into NED by roll, pitch, yaw (ZYX)."""
    roll, pitch, yaw = attitude_rad
    cr, sr, cp, sp, cy, sy = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch), math.cos(yaw), math.sin(yaw)
    x, y, z = v
    return (
        cp * cy * x + (sr * sp * cy - cr * sy) * y + (cr * sp * cy + sr * sy) * z,
        cp * sy * x + (sr * sp * sy + cr * cy) * y + (cr * sp * sy - sr * cy) * z,
        -sp * x + sr * cp * y + cr * cp * z,
    )


def ned_to_body(v: Vec3, attitude_rad: Vec3) -> Vec3:
    """The inverse of :func:`body_to_ned` (the transpose of its rotation)."""
    roll, pitch, yaw = attitude_rad
    cr, sr, cp, sp, cy, sy = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch), math.cos(yaw), math.sin(yaw)
    n, e, d = v
    return (
        cp * cy * n + cp * sy * e - sp * d,
        (sr * sp * cy - cr * sy) * n + (sr * sp * sy + cr * cy) * e + sr * cp * d,
        (cr * sp * cy + sr * sy) * n + (cr * sp * sy - sr * cy) * e + cr * cp * d,
    )


def angles_of(target_body: Vec3) -> tuple[float, float]:
    """(angle_x, angle_y) a downward camera reports for a target at ``target_body`` (FRD):
    the inverse of the ray ``(-tan angle_y, tan angle_x, 1)``."""
    x, y, z = target_body
    if z <= 0:
        raise ValueError("the target is not below the camera")
    return math.atan(y / z), math.atan(-x / z)


def ray_from_angles(angle_x_rad: float, angle_y_rad: float, tangent: bool = True) -> Vec3:
    """The body-frame ray (z = 1) to the target. PX4 feeds the angles to its estimator as if they
    were tangents (``tangent=False``: the IR-LOCK report's convention); ArduPilot takes tan()."""
    ax, ay = (math.tan(angle_x_rad), math.tan(angle_y_rad)) if tangent else (angle_x_rad, angle_y_rad)
    return (-ay, ax, 1.0)


def relative_from_ray(ray_body: Vec3, attitude_rad: Vec3, height_m: float) -> Vec3 | None:
    """The target relative to the vehicle in NED, scaling the ray to ``height_m`` below it (PX4:
    the distance to the ground); None when the ray does not point down."""
    n, e, d = body_to_ned(ray_body, attitude_rad)
    if d < 1e-6:
        return None
    return (n / d * height_m, e / d * height_m, height_m)


class AxisFilter:
    """A constant-velocity Kalman filter on one horizontal axis of the target's position relative
    to the vehicle (PX4's landing target estimator and ArduPilot's PosVelEKF are this filter):
    state (position, velocity), driven by minus the vehicle's acceleration."""

    def __init__(self, position_m: float, velocity_m_s: float, position_var: float, velocity_var: float) -> None:
        self.x = [position_m, velocity_m_s]
        self.p = [[position_var, 0.0], [0.0, velocity_var]]

    def predict(self, dt_s: float, accel_m_s2: float, accel_var: float) -> None:
        """Advance by ``dt_s`` with the relative acceleration ``accel_m_s2`` (white, ``accel_var``)."""
        pos, vel = self.x
        self.x = [pos + vel * dt_s + 0.5 * accel_m_s2 * dt_s * dt_s, vel + accel_m_s2 * dt_s]
        (a, b), (_, d) = self.p
        q = accel_var
        dt2 = dt_s * dt_s
        a2 = a + 2 * dt_s * b + dt2 * d + 0.25 * dt2 * dt2 * q
        b2 = b + dt_s * d + 0.5 * dt2 * dt_s * q
        self.p = [[a2, b2], [b2, d + dt2 * q]]

    def innovation(self, measured_m: float, measurement_var: float) -> tuple[float, float]:
        """(innovation, its variance) of a position measurement."""
        return measured_m - self.x[0], self.p[0][0] + measurement_var

    def nis(self, measured_m: float, measurement_var: float) -> float:
        """Normalised innovation squared: a gate for outliers."""
        innov, s = self.innovation(measured_m, measurement_var)
        return innov * innov / s

    def fuse(self, measured_m: float, measurement_var: float) -> None:
        innov, s = self.innovation(measured_m, measurement_var)
        (a, b), (_, d) = self.p
        k0, k1 = a / s, b / s
        self.x = [self.x[0] + k0 * innov, self.x[1] + k1 * innov]
        self.p = [[(1 - k0) * a, (1 - k0) * b], [(1 - k0) * b, d - k1 * b]]

    def pin_velocity(self, velocity_m_s: float) -> None:
        """Hold the velocity at a known value (a target assumed still: minus the vehicle's)."""
        self.x[1] = velocity_m_s
        self.p = [[self.p[0][0], 0.0], [0.0, 0.0]]


@dataclass(frozen=True)
class TargetEstimate:
    """Where the estimator puts the target: in the vehicle's local (reported) NED frame."""

    time_s: float  # of the last measurement fused
    north_m: float
    east_m: float
    down_m: float
    vn_m_s: float = 0.0  # the target's own velocity (0 when assumed still or not estimated)
    ve_m_s: float = 0.0
