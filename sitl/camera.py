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

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import NamedTuple

import cv2
import numpy as np
from numpy.typing import ArrayLike

from colcommon.camera_geometry import CAM_FROM_BODY, pinhole_matrix, rotation_ned_from_body
from sitl import pad_marker
from sitl.config import CameraConfig
from sitl.world import World

_MIN_DEPTH_M = 1e-3
_MIN_HEIGHT_M = 0.02
_WARP_FLAGS = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
_COVER_MARGIN_PX = 3.0  # the silhouette's anti-aliased edge touches pixels within ~1.5 px of it
_MAX_FILL_COORD = 1 << 18  # hull vertices (1/16 px) beyond this may overflow cv2's fixed point
_INSIDE_MARGIN_TEXELS = 2.0  # far above the float error of OpenCV's mapped coordinates

# Colours (BGR). The pad is a saturated magenta no ground, roof or sky colour comes near in hue.
PAD_BGR = (210, 40, 220)
DOT_BGR = (245, 245, 245)
ROOF_BGR = (150, 150, 145)
SIDE_BGR = (95, 90, 85)
SKY_BGR = (235, 206, 160)
_SIDE_BGRA_SCALAR = (*SIDE_BGR, 255)
_SIDE_BGRA = np.array(_SIDE_BGRA_SCALAR, np.uint8)
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
    """``count`` BGRA levels of a BGR image, each half the size of the one before; read-only,
    since renderers of one process share them (below)."""
    levels = [base]
    for _ in range(count - 1):
        src = levels[-1]
        if wrap:  # filter across the tile's seams so the repeat stays invisible at every level
            padded = np.pad(src, ((4, 4), (4, 4), (0, 0)), mode="wrap")
            levels.append(np.ascontiguousarray(cv2.pyrDown(padded)[2:-2, 2:-2]))
        else:
            levels.append(cv2.pyrDown(src))
    bgra = tuple(cv2.cvtColor(level, cv2.COLOR_BGR2BGRA) for level in levels)
    for level in bgra:
        level.flags.writeable = False
    return bgra


# Made once per process for each set of arguments: a pure function of them, 10 MB and 0.4 s of
# CPU per renderer otherwise (several envs in one process each have a renderer), and every frame
# of every renderer then reads the same textures from the caches.
@lru_cache(maxsize=4)
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


@lru_cache(maxsize=4)
def roof_pyramid(length_m: float, width_m: float, pad_radius_m: float, dot_radius_m: float,
                 marker: str = "none") -> TexturePyramid:
    """The roof (long side north-south) with the pad: a magenta disc and a white centre dot, and
    with ``marker`` one of sitl/pad_marker.py's ArUco boards (``aruco`` drawn over the pad,
    ``aruco-disc`` inked into it), or ``none``."""
    rows, cols = int(round(length_m / _ROOF_TEXEL_M)), int(round(width_m / _ROOF_TEXEL_M))
    base = np.empty((rows, cols, 3), np.uint8)
    base[:] = ROOF_BGR
    edge = max(1, int(0.04 / _ROOF_TEXEL_M))
    cv2.rectangle(base, (0, 0), (cols - 1, rows - 1), SIDE_BGR, edge)
    centre = (int(round((cols - 1) / 2 * 16)), int(round((rows - 1) / 2 * 16)))
    for radius_m, colour in ((pad_radius_m, PAD_BGR), (dot_radius_m, DOT_BGR)):
        cv2.circle(base, centre, int(round(radius_m / _ROOF_TEXEL_M * 16)), colour, -1, cv2.LINE_AA, 4)
    if marker != "none":
        pad_marker.check_fits(marker, length_m, width_m, pad_radius_m, dot_radius_m)
        pad_marker.draw_board(marker, base)
    return TexturePyramid(_pyramid(base, _ROOF_LEVELS, wrap=False), _ROOF_TEXEL_M)


def camera_matrix(cfg: CameraConfig) -> np.ndarray:
    """The pinhole intrinsics K of the module doc (the renderer's; a detector's for its frames)."""
    return pinhole_matrix(cfg.width_px, cfg.height_px, cfg.hfov_deg)


class CameraRenderer:
    """Renders ``HxWx3`` BGR frames and projects world points with the same camera model.

    Not thread-safe: a renderer reuses its scratch buffers from frame to frame (one renderer per
    thread). Every frame returned is a new array.
    """

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
            wc.vehicle_length_m, wc.vehicle_width_m, wc.pad_radius_m, cfg.pad_dot_radius_m, cfg.pad_marker
        )
        # Per-frame constants, computed once (each is the very value the per-frame code used to
        # compute, so frames stay bit-identical; tests/sitl/test_camera_speed_equivalence.py).
        self._k_cam = self.K @ CAM_FROM_BODY
        w, h = self.width_px - 1, self.height_px - 1
        self._corners = np.array([[0, 0], [w, 0], [w, h], [0, h]], dtype=float)
        m = _COVER_MARGIN_PX
        self._cover_corners = np.array([[-m, -m], [w + m, -m], [w + m, h + m], [-m, h + m]], dtype=float)
        n = cfg.ground_downsample
        # Full-resolution pixel x -> reduced pixel (x + 0.5) / n - 0.5 (cv2.resize's convention).
        self._shrink = np.array([[1.0 / n, 0.0, 0.5 / n - 0.5], [0.0, 1.0 / n, 0.5 / n - 0.5], [0.0, 0.0, 1.0]])
        sw, sh = -(-self.width_px // n), -(-self.height_px // n)
        self._small_size = (sw, sh)
        self._small_corners = np.array([[0, 0, 1], [sw - 1, 0, 1], [sw - 1, sh - 1, 1], [0, sh - 1, 1]], dtype=float)
        self._ground_tile_m = self.ground.size_m[0]
        self._half = np.array([wc.vehicle_length_m / 2, wc.vehicle_width_m / 2])
        self._signs = np.array([[1, -1], [1, 1], [-1, 1], [-1, -1]], dtype=float)
        self._roof_z = -wc.vehicle_height_m
        rows, cols = self.roof.levels[0].shape[:2]
        s = self.roof.texel_m(0)
        self._roof_origin_offset = ((rows - 1) / 2 * s, (cols - 1) / 2 * s)
        self._mount_key: tuple | None = None
        self._mount_matrix = np.eye(3)
        # Scratch: the BGRA canvas and the reduced ground (never handed out).
        self._canvas = np.empty((self.height_px, self.width_px, 4), np.uint8)
        self._ground_small = np.empty((sh, sw, 4), np.uint8) if n > 1 else self._canvas

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
            r_nb = r_nb @ self._mount_rotation(mount_rad)
        r_bn = r_nb.T
        m = self._k_cam @ r_bn  # = K @ CAM_FROM_BODY @ r_bn (the product is evaluated left to right)
        pos = np.asarray(position_ned_m, dtype=float)
        proj = np.empty((3, 4))
        proj[:, :3] = m
        proj[:, 3] = -m @ pos
        return proj

    def _mount_rotation(self, mount_rad: ArrayLike) -> np.ndarray:
        """``rotation_ned_from_body(mount_rad)``, kept for the last mounting (an episode's)."""
        key = tuple(mount_rad) if isinstance(mount_rad, tuple) else None
        if key is not None and key == self._mount_key:
            return self._mount_matrix
        matrix = rotation_ned_from_body(mount_rad)
        if key is not None:
            self._mount_key, self._mount_matrix = key, matrix
        return matrix

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
        if not (np.isfinite(pos).all() and np.isfinite(np.asarray(attitude_rad, dtype=float)).all()):
            raise ValueError(f"camera pose must be finite, got position {pos} attitude {np.asarray(attitude_rad)}")
        pos[2] = min(pos[2], -_MIN_HEIGHT_M)  # on (or numerically under) the ground: look from just above it
        proj = self.world_to_image(pos, attitude_rad, mount_rad)
        vehicle = self._vehicle_outline(proj, t_s)
        covered = vehicle is not None and self._covers_image(vehicle)
        # Every homography of the frame first, inverted in one call (np.linalg.inv over a stack
        # inverts each matrix exactly as alone, for a third of the call overhead).
        matrices = []
        if not covered:
            ground_level, ground_h = self._ground_homography(proj, pos)
            matrices += [ground_h, proj[:, :3]]
        roof = None
        if vehicle is not None and pos[2] < self._roof_z:  # the roof is seen only from above it
            roof = self._roof_homography(proj, pos, vehicle)
            if roof is not None:
                matrices.append(roof[2])
        inverses = np.linalg.inv(np.stack(matrices)) if matrices else np.empty((0, 3, 3))
        if covered:
            # The vehicle's opaque silhouette fills the whole frame: ground and sky are hidden.
            image = self._canvas
            image.view(np.uint32).fill(_SIDE_BGRA.view(np.uint32)[0])  # the fill's colour, every pixel
        else:
            image = self._draw_ground(ground_level, inverses[0])
            self._draw_sky(image, inverses[1][2])  # NED down component of the ray through (u, v, 1)
            if vehicle is not None:
                cv2.fillConvexPoly(image, vehicle.hull, _SIDE_BGRA_SCALAR, cv2.LINE_AA, 4)
        if roof is not None:
            level, (x0, y0, x1, y1), _ = roof
            cv2.warpPerspective(  # straight into the canvas: the view is the roof's bounding box
                self.roof.levels[level], inverses[-1], (x1 - x0, y1 - y0), dst=image[y0:y1, x0:x1],
                flags=_WARP_FLAGS, borderMode=cv2.BORDER_TRANSPARENT,
            )
        return cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)

    def _plane_homography(
        self, proj: np.ndarray, pyr: TexturePyramid, level: int, origin_ne: tuple[float, float], z_m: float
    ) -> np.ndarray:
        """Texture pixel (col, row, 1) of a horizontal plane at depth ``z_m`` -> image pixel."""
        s = pyr.texel_m(level)
        n0, e0 = origin_ne
        plane = np.array([[0.0, -s, n0], [s, 0.0, e0], [0.0, 0.0, z_m], [0.0, 0.0, 1.0]])
        return proj @ plane

    def _ground_homography(self, proj: np.ndarray, pos: np.ndarray) -> tuple[int, np.ndarray]:
        """The ground's texture level and its texel -> reduced-image-pixel homography."""
        n = self.cfg.ground_downsample
        pyr = self.ground
        level = pyr.level_for(-pos[2] * n / self.fx)
        tile_m = self._ground_tile_m
        # The repeat of the tile that holds the camera (most frames then need no wrapping).
        origin = (np.round(pos[0] / tile_m) * tile_m + tile_m / 2, np.round(pos[1] / tile_m) * tile_m - tile_m / 2)
        return level, self._shrink @ self._plane_homography(proj, pyr, level, origin, 0.0)

    def _draw_ground(self, level: int, inverse: np.ndarray) -> np.ndarray:
        """The ground, warped at 1/n resolution (n = ground_downsample) and scaled up: it is only
        background, and the warp is the largest cost of a frame. Returns the (reused) canvas."""
        texture = self.ground.levels[level]
        # BORDER_WRAP repeats the tile; when every sample of the frame lies inside one repeat,
        # the border mode is never consulted and OpenCV's BORDER_CONSTANT path, twice as fast,
        # computes the very same pixels.
        border = cv2.BORDER_CONSTANT if _samples_inside(inverse, self._small_corners, texture.shape) else cv2.BORDER_WRAP
        ground = cv2.warpPerspective(
            texture, inverse, self._small_size, dst=self._ground_small, flags=_WARP_FLAGS, borderMode=border
        )
        if self.cfg.ground_downsample == 1:
            return ground
        return cv2.resize(ground, (self.width_px, self.height_px), dst=self._canvas, interpolation=cv2.INTER_LINEAR)

    def _draw_sky(self, image: np.ndarray, ray_down: np.ndarray) -> None:
        """Paint pixels whose ray never meets the ground (only when the horizon is in view).
        ``ray_down``: the last row of the inverse of ``proj[:, :3]``."""
        corners = self._corners
        side = corners @ ray_down[:2] + ray_down[2]
        if (side > 0).all():
            return
        poly = _clip_polygon_half_plane(corners, ray_down)
        if len(poly) >= 3:
            cv2.fillConvexPoly(image, np.round(poly * 16).astype(np.int32), (*SKY_BGR, 255), cv2.LINE_AA, 4)

    def _vehicle_outline(self, proj: np.ndarray, t_s: float) -> _Outline | None:
        """The ground vehicle's box in the image, or None when it is not drawn."""
        centre_ne = self.world.position_ne(t_s)
        xy = centre_ne + self._signs * self._half
        box = np.empty((8, 4))
        box[:4, :2] = xy
        box[4:, :2] = xy
        box[:4, 2] = self._roof_z
        box[4:, 2] = 0.0
        box[:, 3] = 1.0
        uvd = box @ proj.T
        if uvd[:, 2].min() <= _MIN_DEPTH_M:
            return None  # the box reaches behind the camera: only possible far below the approach
        uv = uvd[:, :2] / uvd[:, 2:]
        us, vs = uv[:, 0].tolist(), uv[:, 1].tolist()
        if not (max(us) >= -1 and min(us) <= self.width_px and max(vs) >= -1 and min(vs) <= self.height_px):
            return None
        hull = cv2.convexHull(np.round(uv * 16).astype(np.int32))
        return _Outline(hull, us, vs, centre_ne)

    def _covers_image(self, outline: _Outline) -> bool:
        """Whether the silhouette's fill sets every pixel: the frame, grown by a margin wider than
        the anti-aliased edge, lies strictly inside the hull (in range of OpenCV's fixed point)."""
        m = _COVER_MARGIN_PX
        us, vs = outline.us, outline.vs
        if not (min(us) < -m and min(vs) < -m and max(us) > self.width_px - 1 + m and max(vs) > self.height_px - 1 + m):
            return False
        p = outline.hull.reshape(-1, 2)
        if len(p) < 3 or np.abs(p).max() >= _MAX_FILL_COORD:
            return False
        p = p / 16.0
        edge = np.roll(p, -1, axis=0) - p
        c = self._cover_corners
        cross = edge[:, :1] * (c[:, 1] - p[:, 1:]) - edge[:, 1:] * (c[:, 0] - p[:, :1])
        return bool((cross > 0).all() or (cross < 0).all())

    def _roof_homography(
        self, proj: np.ndarray, pos: np.ndarray, outline: _Outline
    ) -> tuple[int, tuple[int, int, int, int], np.ndarray] | None:
        """The roof's texture level, its bounding box ``(x0, y0, x1, y1)`` in the image (the roof
        is warped into that box only) and its texel -> box pixel homography; None if off-image."""
        us, vs = outline.us[:4], outline.vs[:4]  # the roof's corners
        x0 = max(math.floor(min(us)) - 1, 0)
        y0 = max(math.floor(min(vs)) - 1, 0)
        x1 = min(math.ceil(max(us)) + 2, self.width_px)
        y1 = min(math.ceil(max(vs)) + 2, self.height_px)
        if x1 <= x0 or y1 <= y0:
            return None
        pyr = self.roof
        roof_z = self._roof_z
        level = pyr.level_for((roof_z - pos[2]) / self.fx)
        dn, de = self._roof_origin_offset
        centre_ne = outline.centre_ne
        origin = (centre_ne[0] + dn, centre_ne[1] - de)
        h = self._plane_homography(proj, pyr, level, origin, roof_z)
        shift = np.array([[1.0, 0.0, -x0], [0.0, 1.0, -y0], [0.0, 0.0, 1.0]])
        return level, (x0, y0, x1, y1), shift @ h


class _Outline(NamedTuple):
    """The vehicle box in the image: its silhouette's convex hull (1/16 px, for cv2's shift 4),
    the corners' u and v (roof corners first) and the vehicle's centre (north, east)."""

    hull: np.ndarray
    us: list[float]
    vs: list[float]
    centre_ne: np.ndarray


def _samples_inside(inverse: np.ndarray, corners: np.ndarray, shape: tuple[int, ...]) -> bool:
    """Whether the warp with ``inverse`` (destination pixel -> texture pixel) samples only
    texels at least ``_INSIDE_MARGIN_TEXELS`` inside the texture, bilinear neighbours included.
    The image of the destination rectangle is the quadrilateral of its corners' images when the
    homogeneous w has one sign over it (w is affine, so checking the corners suffices)."""
    mapped = (corners @ inverse.T).tolist()
    if not (all(w > 0 for _, _, w in mapped) or all(w < 0 for _, _, w in mapped)):
        return False
    m = _INSIDE_MARGIN_TEXELS
    cols, rows = shape[1] - 1 - m, shape[0] - 1 - m
    return all(m <= x / w <= cols and m <= y / w <= rows for x, y, w in mapped)


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
