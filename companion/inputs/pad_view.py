"""What a person judges from the camera view: where the pad is and how high we are above it.

The camera looks straight down and is fixed to the body. Image ``u`` grows towards body right
and ``v`` towards body backward (the top of the image is body forward; see docs/camera.md).
A pinhole model with the horizontal field of view turns the pad's pixel position into a ray,
the attitude levels the ray, and the pad's apparent radius gives the height above it. No
ground truth is used: only what is on the screen plus the attitude a pilot feels or sees.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from companion.msg.pad import PadDetection


@dataclass(frozen=True)
class PadEstimate:
    """The pad relative to the camera, in the level, heading-aligned frame."""

    forward_m: float
    right_m: float
    height_m: float
    edge_fraction: float
    """How far towards the image border the pad's centre is: 0 at the centre, 1 at the edge."""
    partial: bool

    @property
    def offset_m(self) -> float:
        """Horizontal distance to the pad's centre."""
        return math.hypot(self.forward_m, self.right_m)


def focal_length_px(width_px: float, hfov_rad: float) -> float:
    """Pinhole focal length from the image width and horizontal field of view."""
    return (width_px / 2.0) / math.tan(hfov_rad / 2.0)


def image_centre_px(size_px: tuple[float, float]) -> tuple[float, float]:
    """Principal point; pixel centres sit at integer coordinates (OpenCV's convention)."""
    return (size_px[0] - 1) / 2.0, (size_px[1] - 1) / 2.0


def pixel_to_body_ray(
    u_px: float, v_px: float, size_px: tuple[float, float], focal_px: float
) -> np.ndarray:
    """The body-frame (FRD) direction through a pixel, scaled to a down component of 1."""
    cx, cy = image_centre_px(size_px)
    return np.array([-(v_px - cy) / focal_px, (u_px - cx) / focal_px, 1.0])


def level(ray_body: np.ndarray, roll_rad: float, pitch_rad: float) -> np.ndarray:
    """Rotate a body-frame vector into the level, heading-aligned frame (undo roll and pitch)."""
    cr, sr = math.cos(roll_rad), math.sin(roll_rad)
    cp, sp = math.cos(pitch_rad), math.sin(pitch_rad)
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    return ry @ rx @ ray_body


def edge_fraction(u_px: float, v_px: float, size_px: tuple[float, float]) -> float:
    """0 at the image centre, 1 on the nearest border (beyond 1 outside)."""
    cx, cy = image_centre_px(size_px)
    return max(abs(u_px - cx) / cx, abs(v_px - cy) / cy)


def estimate_pad(
    pad: PadDetection,
    size_px: tuple[float, float],
    attitude_rad: tuple[float, float, float],
    pad_radius_m: float,
    hfov_rad: float,
) -> PadEstimate:
    """Pad position and height above it from a detection, as a person reads the screen."""
    u_px, v_px = float(pad.u_px), float(pad.v_px)
    radius_px = max(float(pad.radius_px), 1e-3)
    f_px = focal_length_px(size_px[0], hfov_rad)
    height_m = f_px * pad_radius_m / radius_px
    ray = level(pixel_to_body_ray(u_px, v_px, size_px, f_px), attitude_rad[0], attitude_rad[1])
    down = max(ray[2], 1e-3)  # a ray at or above the horizon cannot see the pad; stay finite
    return PadEstimate(
        forward_m=float(ray[0] / down * height_m),
        right_m=float(ray[1] / down * height_m),
        height_m=height_m,
        edge_fraction=edge_fraction(u_px, v_px, size_px),
        partial=bool(pad.partial),
    )


def heading_velocity(velocity_ned_m_s: tuple[float, float, float], yaw_rad: float) -> np.ndarray:
    """Ground velocity as (forward, right, down) in the level, heading-aligned frame."""
    vn, ve, vd = velocity_ned_m_s
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    return np.array([c * vn + s * ve, -s * vn + c * ve, vd])
