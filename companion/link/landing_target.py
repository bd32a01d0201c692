"""LANDING_TARGET from a pad pose: what the companion tells an autopilot's precision landing.

The contract with the vehicle (our SITL's PX4 and ArduPilot personalities honour exactly this;
real PX4 and ArduCopter read the same fields, as noted):

LANDING_TARGET (MAVLink 2, id 149), one per camera frame in which the board is decoded,
from the companion's component, after the precision landing was asked for:

- ``time_usec``: the frame's stamp, the vehicle's ``time_boot_ms`` of the pose the image shows,
  times 1000 (time since the vehicle's boot, not Unix time).
- ``target_num`` 0; ``type`` LANDING_TARGET_TYPE_VISION_FIDUCIAL (2); ``position_valid`` 1.
- ``angle_x``, ``angle_y`` (rad): the pad centre's angles off the optical axis,
  ``atan(x_cam / z_cam)``, ``atan(y_cam / z_cam)``; image x is body right, image y is body
  backwards (the camera looks down, the top of the image forward). ``distance`` (m): from the
  camera to the pad centre. ``size_x``, ``size_y`` (rad): the decoded markers' angular extent.
- ``frame``, ``x``, ``y``, ``z``, ``q`` by autopilot (the dialect's ``landing_target_frame``):
  PX4: ``MAV_FRAME_LOCAL_NED`` (1); x, y, z the pad centre in the vehicle's own local frame
  (the frame of its LOCAL_POSITION_NED, not relative to home): PX4 publishes exactly these as
  the target's absolute position (landing_target_pose x_abs, y_abs, z_abs) and precland flies
  to them; it ignores the angles when position_valid is 1, and refuses any other frame.
  ArduPilot: ``MAV_FRAME_BODY_FRD`` (12); x, y, z the pad centre from the vehicle in body axes
  (forward, right, down): AC_PrecLand's MAVLink backend divides them by ``distance`` for its
  line of sight and refuses other frames ("Plnd: Frame not supported").
  ``q`` (w, x, y, z): the pad frame (north, east, down of the roof) in that frame.

When the pad is not seen, nothing is sent. Not ``position_valid`` 0: both autopilots read a
message with position_valid 0 as an *angle* measurement (PX4 as an IR-LOCK report, ArduPilot as
a line of sight ``(-tan angle_y, tan angle_x, 1)``), so zeros would say "dead below". Silence is
how both learn the target is lost (PX4: PLD_BTOUT; ArduPilot: 1 s without a measurement).

Asking for the landing (companion/link/dialect.py ``precland_*``): PX4: MAV_CMD_DO_SET_MODE with
param1 = MAV_MODE_FLAG_CUSTOM_MODE_ENABLED (| SAFETY_ARMED), param2 = 4 (AUTO), param3 = 9
(PRECLAND); the HEARTBEAT then shows custom mode ``4 << 16 | 9 << 24``; nothing before.
ArduPilot makes its precision landing at boot (set at run time, LAND lands straight down:
"PrecLand: Failsafe Measures"), so before the run's first arming the companion reads
``PLND_ENABLED`` and ``PLND_TYPE``; unless both are 1 it sets them (PARAM_SET, each echoed by
PARAM_VALUE), sends MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN param1 = 1 while disarmed (never armed),
waits for the autopilot's HEARTBEAT to stop and come back (LinkTimeout saying which did not),
and asks for its streams again (ArduCopter boots sending HEARTBEAT and SYS_STATUS only). At the
hand-over: PARAM_SET ``PLND_ENABLED`` = 1 and ``PLND_TYPE`` = 1 again (echo checked), then
MAV_CMD_DO_SET_MODE to LAND (custom mode 9). In lockstep the companion still answers every frame
with its usual SET_POSITION_TARGET_LOCAL_NED echo (zero body velocity), sent after the frame's
LANDING_TARGET: the SITL advances on it and does not fly it outside OFFBOARD / GUIDED.
Touchdown is the vehicle's own: EXTENDED_SYS_STATE landed_state ON_GROUND.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike

from colcommon.camera_geometry import CAM_FROM_BODY, rotation_ned_from_body

MAV_FRAME_LOCAL_NED = 1
MAV_FRAME_BODY_FRD = 12
LANDING_TARGET_TYPE_VISION_FIDUCIAL = 2
FRAMES = (MAV_FRAME_LOCAL_NED, MAV_FRAME_BODY_FRD)
UINT64_MAX = 2**64 - 1


class TargetPose(Protocol):
    """What a detector tells of the pad (companion.vision.aruco.PadPose): its centre and
    orientation in OpenCV's camera frame (x right, y down, z along the axis), its corners' pixels."""

    @property
    def position_cam_m(self) -> tuple[float, float, float]: ...

    @property
    def rotation(self) -> np.ndarray: ...

    @property
    def corners_px(self) -> Sequence[tuple[float, float]]: ...


@dataclass(frozen=True)
class LandingTarget:
    """The fields of one LANDING_TARGET message, named and ordered as MAVLink's, SI units."""

    time_usec: int
    target_num: int
    frame: int
    angle_x: float
    angle_y: float
    distance: float
    size_x: float
    size_y: float
    x: float
    y: float
    z: float
    q: tuple[float, float, float, float]
    type: int = LANDING_TARGET_TYPE_VISION_FIDUCIAL
    position_valid: int = 1

    def __post_init__(self) -> None:
        floats = (self.angle_x, self.angle_y, self.distance, self.size_x, self.size_y, self.x, self.y, self.z, *self.q)
        if not all(math.isfinite(v) for v in floats):
            raise ValueError(f"LANDING_TARGET fields must be finite (an autopilot would fly to NaN), got {self}")
        if not 0 <= self.time_usec <= UINT64_MAX:
            raise ValueError(f"time_usec {self.time_usec} does not fit MAVLink's uint64")
        if not 0 <= self.target_num <= 255:
            raise ValueError(f"target_num {self.target_num} does not fit a uint8")
        if self.frame not in FRAMES:
            raise ValueError(f"frame {self.frame} is neither MAV_FRAME_LOCAL_NED (1, PX4) nor MAV_FRAME_BODY_FRD (12, ArduPilot)")
        if self.distance <= 0:
            raise ValueError(f"distance must be > 0 (ArduPilot drops a target at distance 0), got {self.distance}")
        if abs(math.hypot(*self.q) - 1.0) > 1e-6:
            raise ValueError(f"q must be a unit quaternion (w, x, y, z), got {self.q}")

    def encode_args(self) -> tuple[object, ...]:
        """Positional arguments of pymavlink's ``landing_target_encode``."""
        return (self.time_usec, self.target_num, self.frame, self.angle_x, self.angle_y, self.distance,
                self.size_x, self.size_y, self.x, self.y, self.z, list(self.q), self.type, self.position_valid)


def quaternion(rotation: ArrayLike) -> tuple[float, float, float, float]:
    """(w, x, y, z) of a rotation matrix, w >= 0 (Shepperd's method: stable for every rotation)."""
    m = np.asarray(rotation, dtype=float)
    trace = float(np.trace(m))
    candidates = [trace, m[0, 0], m[1, 1], m[2, 2]]
    k = int(np.argmax(candidates))
    if k == 0:
        s = 2.0 * math.sqrt(1.0 + trace)
        q = [s / 4, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    else:
        i, j, n = k - 1, k % 3, (k + 1) % 3
        s = 2.0 * math.sqrt(1.0 + m[i, i] - m[j, j] - m[n, n])
        q = [0.0] * 4
        q[0] = (m[n, j] - m[j, n]) / s
        q[1 + i] = s / 4
        q[1 + j] = (m[j, i] + m[i, j]) / s
        q[1 + n] = (m[n, i] + m[i, n]) / s
    arr = np.array(q) / np.linalg.norm(q)
    if arr[0] < 0:
        arr = -arr
    return (float(arr[0]), float(arr[1]), float(arr[2]), float(arr[3]))


def angular_size(corners_px: ArrayLike, camera_matrix: ArrayLike) -> tuple[float, float]:
    """(size_x, size_y) in rad: the angle the decoded corners span along image x and image y."""
    pts = np.asarray(corners_px, dtype=float).reshape(-1, 2)
    k = np.asarray(camera_matrix, dtype=float)
    ax = np.arctan((pts[:, 0] - k[0, 2]) / k[0, 0])
    ay = np.arctan((pts[:, 1] - k[1, 2]) / k[1, 1])
    return float(ax.max() - ax.min()), float(ay.max() - ay.min())


def landing_target(pose: TargetPose, camera_matrix: ArrayLike, time_boot_ms: int, frame: int,
                   attitude_rad: ArrayLike = (0.0, 0.0, 0.0),
                   position_ned_m: ArrayLike = (0.0, 0.0, 0.0), target_num: int = 0) -> LandingTarget:
    """The LANDING_TARGET for one detection (see the module doc for each field).

    ``attitude_rad`` (roll, pitch, yaw) and ``position_ned_m`` (the vehicle's, in its own local
    frame) at the frame's time are needed for MAV_FRAME_LOCAL_NED only; ValueError if they, or
    anything else, are not finite."""
    if frame not in FRAMES:
        raise ValueError(f"frame {frame} is neither MAV_FRAME_LOCAL_NED (1) nor MAV_FRAME_BODY_FRD (12)")
    att = np.asarray(attitude_rad, dtype=float).reshape(3)
    pos = np.asarray(position_ned_m, dtype=float).reshape(3)
    if not (np.isfinite(att).all() and np.isfinite(pos).all()):
        raise ValueError(f"vehicle attitude {att} and position {pos} must be finite to place the target")
    t_cam = np.asarray(pose.position_cam_m, dtype=float)
    body_from_cam = CAM_FROM_BODY.T
    t_body = body_from_cam @ t_cam
    r_body_pad = body_from_cam @ pose.rotation
    if frame == MAV_FRAME_BODY_FRD:
        where, orientation = t_body, r_body_pad
    else:
        r_nb = rotation_ned_from_body(att)
        where, orientation = pos + r_nb @ t_body, r_nb @ r_body_pad
    size_x, size_y = angular_size(pose.corners_px, camera_matrix)
    return LandingTarget(
        time_usec=int(time_boot_ms) * 1000, target_num=target_num, frame=frame,
        angle_x=math.atan2(t_cam[0], t_cam[2]), angle_y=math.atan2(t_cam[1], t_cam[2]),
        distance=float(np.linalg.norm(t_cam)), size_x=size_x, size_y=size_y,
        x=float(where[0]), y=float(where[1]), z=float(where[2]), q=quaternion(orientation),
    )
