"""The SITL's downward camera: a pinhole view of the world rendered from the true pose.

Mounting (body-fixed, no gimbal): the optical axis is body +z (down). Image ``u`` (columns,
to the right) is body +y (right wing); image ``v`` (rows, down) is body -x (towards the tail),
so the top of the image looks forward. With yaw 0 and a level vehicle, the top of the image is
north and the right is east. Pixel centres sit at integer coordinates (OpenCV's convention):
``cx = (width - 1) / 2``, ``cy = (height - 1) / 2``, square pixels ``fx = fy = (width / 2) /
tan(hfov / 2)``.

The world is two textured planes and a box: the ground (z = 0, a seeded procedural tile that
repeats) and the ground vehicle's roof (z = -vehicle_height_m) carrying the pad, plus the
vehicle's sides as a flat silhouette. Each plane is drawn with one ``cv2.warpPerspective`` of a
pre-filtered texture level chosen from the height above it (mip-mapping keeps edges smooth, which
the detector's sub-pixel accuracy relies on). See docs/camera.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike

from sitl.config import CameraConfig
from sitl.world import World

# Camera axes (right, down, optical) expressed in body FRD axes: u = body +y, v = body -x.
CAM_FROM_BODY = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
_MIN_DEPTH_M = 1e-3
_MIN_HEIGHT_M = 0.02
_WARP_FLAGS = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP

# Colours (BGR). The pad is a saturated magenta no ground, roof or sky colour comes near in hue.
PAD_BGR = (210, 40, 220)
DOT_BGR = (245, 245, 245)
ROOF_BGR = (150, 150, 145)
SIDE_BGR = (95, 90, 85)
SKY_BGR = (235, 206, 160)
_GROUND_TILE_M = 16.0
_GROUND_TEXEL_M = 0.02
_ROOF_TEXEL_M = 0.0025
_ROOF_LEVELS = 6
_GROUND_LEVELS = 4


@dataclass(frozen=True)
class TexturePyramid:
    """A top-down texture at several resolutions; level L has texels of ``base * 2**L`` metres.

    Texel (row 0, col 0) has the same centre at every level (``cv2.pyrDown`` keeps even samples).
    """

    levels: tuple[np.ndarray, ...]  # BGRA: OpenCV warps 4-channel images about twice as fast
    base_texel_m: float

    def texel_m(self, level: int) -> float:
        return self.base_texel_m * 2.0**level

    @property
    def size_m(self) -> tuple[float, float]:
        rows, cols = self.levels[0].shape[:2]
        return rows * self.base_texel_m, cols * self.base_texel_m

    def level_for(self, footprint_m: float) -> int:
        """The coarsest level whose texels are still no larger than one image pixel's footprint."""
        if footprint_m <= self.base_texel_m:
            return 0
        return min(int(np.log2(footprint_m / self.base_texel_m)), len(self.levels) - 1)


def _periodic_noise(rng: np.random.Generator, n: int, cycles: float) -> np.ndarray:
    """Seamlessly tiling noise in [-1, 1] with features about ``n / cycles`` texels wide."""
    k = np.fft.fftfreq(n) * n
    kk = np.hypot(k[:, None], k[None, :])
    spectrum = np.fft.fft2(rng.standard_normal((n, n))) * np.exp(-((kk / cycles) ** 2))
    field = np.real(np.fft.ifft2(spectrum))
    return field / (np.abs(field).max() + 1e-12)


def _pyramid(base: np.ndarray, count: int, wrap: bool) -> tuple[np.ndarray, ...]:
    """``count`` BGRA levels of a BGR image, each half the size of the one before."""
    levels = [base]
    for _ in range(count - 1):
        src = levels[-1]
        if wrap:  # filter across the tile's seams so the repeat stays invisible at every level
            padded = np.pad(src, ((4, 4), (4, 4), (0, 0)), mode="wrap")
            levels.append(np.ascontiguousarray(cv2.pyrDown(padded)[2:-2, 2:-2]))
        else:
            levels.append(cv2.pyrDown(src))
    return tuple(cv2.cvtColor(level, cv2.COLOR_BGR2BGRA) for level in levels)


def ground_pyramid(seed: int) -> TexturePyramid:
    """Grass and dirt patches with fine grain: seeded, procedural, repeating every 16 m."""
    rng = np.random.default_rng(seed)
    n = int(round(_GROUND_TILE_M / _GROUND_TEXEL_M))
    patches = np.clip(_periodic_noise(rng, n, 4.0) * 2.5 + 0.5, 0.0, 1.0)[..., None]
    grass = np.array([45.0, 105.0, 60.0]) * (1.0 + 0.25 * _periodic_noise(rng, n, 40.0))[..., None]
    dirt = np.array([70.0, 100.0, 125.0]) * (1.0 + 0.2 * _periodic_noise(rng, n, 25.0))[..., None]
    grain = 18.0 * _periodic_noise(rng, n, 250.0)[..., None]
    base = np.clip(patches * grass + (1.0 - patches) * dirt + grain, 0, 255).astype(np.uint8)
    return TexturePyramid(_pyramid(base, _GROUND_LEVELS, wrap=True), _GROUND_TEXEL_M)


def roof_pyramid(length_m: float, width_m: float, pad_radius_m: float, dot_radius_m: float) -> TexturePyramid:
    """The roof (long side north-south) with the pad: a magenta disc and a white centre dot."""
    rows, cols = int(round(length_m / _ROOF_TEXEL_M)), int(round(width_m / _ROOF_TEXEL_M))
    base = np.empty((rows, cols, 3), np.uint8)
    base[:] = ROOF_BGR
    edge = max(1, int(0.04 / _ROOF_TEXEL_M))
    cv2.rectangle(base, (0, 0), (cols - 1, rows - 1), SIDE_BGR, edge)
    centre = (int(round((cols - 1) / 2 * 16)), int(round((rows - 1) / 2 * 16)))
    for radius_m, colour in ((pad_radius_m, PAD_BGR), (dot_radius_m, DOT_BGR)):
        cv2.circle(base, centre, int(round(radius_m / _ROOF_TEXEL_M * 16)), colour, -1, cv2.LINE_AA, 4)
    return TexturePyramid(_pyramid(base, _ROOF_LEVELS, wrap=False), _ROOF_TEXEL_M)


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


class CameraRenderer:
    """Renders ``HxWx3`` BGR frames and projects world points with the same camera model."""

    def __init__(self, cfg: CameraConfig, world: World) -> None:
        self.cfg = cfg
        self.world = world
        self.width_px, self.height_px = cfg.width_px, cfg.height_px
        self.fx = self.fy = (cfg.width_px / 2.0) / np.tan(np.radians(cfg.hfov_deg) / 2.0)
        self.cx, self.cy = (cfg.width_px - 1) / 2.0, (cfg.height_px - 1) / 2.0
        self.K = np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])
        wc = world.cfg
        self.ground: TexturePyramid = ground_pyramid(cfg.texture_seed)
        self.roof: TexturePyramid = roof_pyramid(
            wc.vehicle_length_m, wc.vehicle_width_m, wc.pad_radius_m, cfg.pad_dot_radius_m
        )

    @property
    def vfov_rad(self) -> float:
        return 2.0 * float(np.arctan((self.height_px / 2.0) / self.fy))

    def world_to_image(
        self, position_ned_m: ArrayLike, attitude_rad: ArrayLike, mount_rad: ArrayLike | None = None
    ) -> np.ndarray:
        """3x4 matrix P with ``[u*w, v*w, w] = P @ [n, e, d, 1]`` (w = depth along the axis).

        ``mount_rad``: the camera's misalignment on the body, roll/pitch/yaw (ZYX) of the
        camera's mounting axes in body axes; None (or omitted) is the nominal mounting.
        """
        r_nb = rotation_ned_from_body(attitude_rad)
        if mount_rad is not None:
            r_nb = r_nb @ rotation_ned_from_body(mount_rad)
        r_bn = r_nb.T
        m = self.K @ CAM_FROM_BODY @ r_bn
        pos = np.asarray(position_ned_m, dtype=float)
        return np.hstack([m, (-m @ pos)[:, None]])

    def project(
        self, point_ned_m: ArrayLike, position_ned_m: ArrayLike, attitude_rad: ArrayLike,
        mount_rad: ArrayLike | None = None,
    ) -> tuple[float, float] | None:
        """Ground-truth pixel ``(u, v)`` of a world point; None if it is behind the camera."""
        p = self.world_to_image(position_ned_m, attitude_rad, mount_rad) @ np.append(np.asarray(point_ned_m, float), 1.0)
        if p[2] <= _MIN_DEPTH_M:
            return None
        return float(p[0] / p[2]), float(p[1] / p[2])

    def project_many(self, points_ned_m: ArrayLike, position_ned_m: ArrayLike, attitude_rad: ArrayLike) -> np.ndarray:
        """``(N, 3)`` rows of ``u, v, depth_m`` (depth <= 0: behind the camera, u, v meaningless)."""
        pts = np.asarray(points_ned_m, dtype=float)
        p = np.hstack([pts, np.ones((len(pts), 1))]) @ self.world_to_image(position_ned_m, attitude_rad).T
        depth = p[:, 2]
        safe = np.where(np.abs(depth) < 1e-9, 1e-9, depth)
        return np.column_stack([p[:, 0] / safe, p[:, 1] / safe, depth])

    def render(
        self, position_ned_m: ArrayLike, attitude_rad: ArrayLike, t_s: float, mount_rad: ArrayLike | None = None
    ) -> np.ndarray:
        """The camera image at pose (NED position, roll/pitch/yaw) and world time ``t_s``, with
        the camera misaligned by ``mount_rad`` (see :meth:`world_to_image`)."""
        pos = np.array(position_ned_m, dtype=float)
        if not (np.all(np.isfinite(pos)) and np.all(np.isfinite(np.asarray(attitude_rad, dtype=float)))):
            raise ValueError(f"camera pose must be finite, got position {pos} attitude {np.asarray(attitude_rad)}")
        pos[2] = min(pos[2], -_MIN_HEIGHT_M)  # on (or numerically under) the ground: look from just above it
        proj = self.world_to_image(pos, attitude_rad, mount_rad)
        image = self._draw_ground(proj, pos)
        self._draw_sky(image, proj)
        self._draw_vehicle(image, proj, pos, t_s)
        return cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)

    def _plane_homography(
        self, proj: np.ndarray, pyr: TexturePyramid, level: int, origin_ne: tuple[float, float], z_m: float
    ) -> np.ndarray:
        """Texture pixel (col, row, 1) of a horizontal plane at depth ``z_m`` -> image pixel."""
        s = pyr.texel_m(level)
        n0, e0 = origin_ne
        plane = np.array([[0.0, -s, n0], [s, 0.0, e0], [0.0, 0.0, z_m], [0.0, 0.0, 1.0]])
        return proj @ plane

    def _draw_ground(self, proj: np.ndarray, pos: np.ndarray) -> np.ndarray:
        """The ground, warped at 1/n resolution (n = ground_downsample) and scaled up: it is only
        background, and the warp is the largest cost of a frame."""
        n = self.cfg.ground_downsample
        pyr = self.ground
        level = pyr.level_for(-pos[2] * n / self.fx)
        tile_m = pyr.size_m[0]
        # Centre one repeat of the tile under the camera: most samples then need no wrapping.
        origin = (np.round(pos[0] / tile_m) * tile_m + tile_m / 2, np.round(pos[1] / tile_m) * tile_m - tile_m / 2)
        # Full-resolution pixel x -> reduced pixel (x + 0.5) / n - 0.5 (cv2.resize's convention).
        shrink = np.array([[1.0 / n, 0.0, 0.5 / n - 0.5], [0.0, 1.0 / n, 0.5 / n - 0.5], [0.0, 0.0, 1.0]])
        h = shrink @ self._plane_homography(proj, pyr, level, origin, 0.0)
        small = (-(-self.width_px // n), -(-self.height_px // n))
        ground = cv2.warpPerspective(
            pyr.levels[level], np.linalg.inv(h), small, flags=_WARP_FLAGS, borderMode=cv2.BORDER_WRAP
        )
        if n == 1:
            return ground
        return cv2.resize(ground, (self.width_px, self.height_px), interpolation=cv2.INTER_LINEAR)

    def _draw_sky(self, image: np.ndarray, proj: np.ndarray) -> None:
        """Paint pixels whose ray never meets the ground (only when the horizon is in view)."""
        ray_down = np.linalg.inv(proj[:, :3])[2]  # NED down component of the ray through (u, v, 1)
        w, h = self.width_px - 1, self.height_px - 1
        corners = np.array([[0, 0], [w, 0], [w, h], [0, h]], dtype=float)
        side = corners @ ray_down[:2] + ray_down[2]
        if np.all(side > 0):
            return
        poly = _clip_polygon_half_plane(corners, ray_down)
        if len(poly) >= 3:
            cv2.fillConvexPoly(image, np.round(poly * 16).astype(np.int32), (*SKY_BGR, 255), cv2.LINE_AA, 4)

    def _draw_vehicle(self, image: np.ndarray, proj: np.ndarray, pos: np.ndarray, t_s: float) -> None:
        wc = self.world.cfg
        centre_ne = self.world.position_ne(t_s)
        half = np.array([wc.vehicle_length_m / 2, wc.vehicle_width_m / 2])
        signs = np.array([[1, -1], [1, 1], [-1, 1], [-1, -1]], dtype=float)
        roof_z = -wc.vehicle_height_m
        corners = np.vstack(
            [np.column_stack([centre_ne + signs * half, np.full(4, z)]) for z in (roof_z, 0.0)]
        )
        uvd = np.hstack([corners, np.ones((8, 1))]) @ proj.T
        if np.any(uvd[:, 2] <= _MIN_DEPTH_M):
            return  # the box reaches behind the camera: only possible far below the approach
        uv = uvd[:, :2] / uvd[:, 2:]
        if not _overlaps_image(uv, self.width_px, self.height_px):
            return
        hull = cv2.convexHull(np.round(uv * 16).astype(np.int32))
        cv2.fillConvexPoly(image, hull, (*SIDE_BGR, 255), cv2.LINE_AA, 4)
        if pos[2] < roof_z:  # the roof is seen only from above it
            self._draw_roof(image, proj, pos, uv[:4], centre_ne, roof_z)

    def _draw_roof(
        self, image: np.ndarray, proj: np.ndarray, pos: np.ndarray, roof_uv: np.ndarray, centre_ne: np.ndarray, roof_z: float
    ) -> None:
        """Warp the roof texture into the roof's bounding box only (cheap), keeping what is outside."""
        x0, y0 = np.maximum(np.floor(roof_uv.min(axis=0)).astype(int) - 1, 0)
        x1 = min(int(np.ceil(roof_uv[:, 0].max())) + 2, self.width_px)
        y1 = min(int(np.ceil(roof_uv[:, 1].max())) + 2, self.height_px)
        if x1 <= x0 or y1 <= y0:
            return
        pyr = self.roof
        level = pyr.level_for((roof_z - pos[2]) / self.fx)
        s = pyr.texel_m(0)
        rows, cols = pyr.levels[0].shape[:2]
        origin = (centre_ne[0] + (rows - 1) / 2 * s, centre_ne[1] - (cols - 1) / 2 * s)
        h = self._plane_homography(proj, pyr, level, origin, roof_z)
        shift = np.array([[1.0, 0.0, -x0], [0.0, 1.0, -y0], [0.0, 0.0, 1.0]])
        roi = np.ascontiguousarray(image[y0:y1, x0:x1])
        cv2.warpPerspective(
            pyr.levels[level], np.linalg.inv(shift @ h), (x1 - x0, y1 - y0), dst=roi,
            flags=_WARP_FLAGS, borderMode=cv2.BORDER_TRANSPARENT,
        )
        image[y0:y1, x0:x1] = roi


def _overlaps_image(uv: np.ndarray, width: int, height: int) -> bool:
    return bool(uv[:, 0].max() >= -1 and uv[:, 0].min() <= width and uv[:, 1].max() >= -1 and uv[:, 1].min() <= height)


def _clip_polygon_half_plane(poly: np.ndarray, line: np.ndarray) -> np.ndarray:
    """The part of a convex polygon where ``a*u + b*v + c <= 0`` (Sutherland-Hodgman, one edge)."""
    out = []
    vals = poly @ line[:2] + line[2]
    for i in range(len(poly)):
        j = (i + 1) % len(poly)
        if vals[i] <= 0:
            out.append(poly[i])
        if (vals[i] <= 0) != (vals[j] <= 0):
            t = vals[i] / (vals[i] - vals[j])
            out.append(poly[i] + t * (poly[j] - poly[i]))
    return np.array(out)
