"""The downward camera's geometry, which the SITL's renderer and the companion's precision landing
(companion/link/landing_target.py) must share exactly: the camera's axes in the body frame, the
body's attitude as a rotation, and the pinhole intrinsics from the image size and field of view.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

# Camera axes (right, down, optical) expressed in body FRD axes: u = body +y, v = body -x.
CAM_FROM_BODY = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


def pinhole_matrix(width_px: int, height_px: int, hfov_deg: float) -> np.ndarray:
    """The pinhole intrinsics K (the renderer's; a detector's for its frames)."""
    f = (width_px / 2.0) / np.tan(np.radians(hfov_deg) / 2.0)
    return np.array([[f, 0.0, (width_px - 1) / 2.0], [0.0, f, (height_px - 1) / 2.0], [0.0, 0.0, 1.0]])


def rotation_ned_from_body(attitude_rad: ArrayLike) -> np.ndarray:
    """Body FRD -> NED rotation from roll, pitch, yaw (aerospace ZYX order)."""
    roll, pitch, yaw = (float(a) for a in np.asarray(attitude_rad, dtype=float).reshape(3))
    cr, sr, cp, sp, cy, sy = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch), np.cos(yaw), np.sin(yaw)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )
