# ruff: noqa
"""Frozen reference: the camera renderer and pad detector as they were before the speed work
(sitl/camera.py and companion/vision/perception.py at commit c30deeb), kept verbatim below the
two marked lines so tests/sitl/test_camera_speed_equivalence.py can require the optimised code to
give bit-identical images and detections. Do not edit or "improve" this file: its only job is to
be the old behaviour. Only what rendering and detection need is kept (the renderer's render path
and the whole detector).
"""

# ---- sitl/camera.py (verbatim from here) ----
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


# ---- companion/vision/perception.py (verbatim from here) ----
import math
from dataclasses import dataclass

import cv2
import numpy as np

from companion.config import PerceptionConfig

_EDGE_HALF_PX = 0.5  # contour points are boundary pixel centres: the edge is half a pixel further
_MIN_ARC_POINTS = 12
_NOTCH_DEPTH_PX = 1.5  # deeper dents in the outline are not the rim
_MAX_FIT_RADIUS_IMAGES = 4.0  # a fitted rim larger than this many image sizes is not the pad
_DOT_AREA_RATIO = (0.005, 0.2)  # (dot / disc) area; the marking's is 0.04


@dataclass(frozen=True)
class PadDetection:
    """The pad in the image: centre and radius in pixels; ``partial`` if it crosses the border."""

    u_px: float
    v_px: float
    radius_px: float
    partial: bool

    def __post_init__(self) -> None:
        if not all(math.isfinite(x) for x in (self.u_px, self.v_px, self.radius_px)):
            raise ValueError(f"pad detection must be finite, got {self}")
        if self.radius_px <= 0:
            raise ValueError(f"pad radius must be positive, got {self.radius_px}")


class PadDetector:
    """Stateless: each frame is judged alone, so a missed frame never poisons the next."""

    def __init__(self, cfg: PerceptionConfig | None = None) -> None:
        cfg = cfg or PerceptionConfig()
        self.cfg = cfg
        self._lo = np.array([cfg.hue_min, cfg.saturation_min, cfg.value_min], np.uint8)
        self._hi = np.array([cfg.hue_max, 255, 255], np.uint8)

    def mask(self, image_bgr: np.ndarray) -> np.ndarray:
        """Binary mask (0/255) of pad-coloured pixels."""
        if image_bgr.ndim != 3 or image_bgr.shape[2] != 3 or image_bgr.dtype != np.uint8:
            raise ValueError(f"expected an HxWx3 uint8 BGR image, got {image_bgr.dtype} {image_bgr.shape}")
        return cv2.inRange(cv2.cvtColor(image_bgr, cv2.COLOR_BGR2HSV), self._lo, self._hi)

    def detect(self, image_bgr: np.ndarray) -> PadDetection | None:
        """The pad, or None when no pad-coloured convex blob of the minimum size is in view."""
        contours, hierarchy = cv2.findContours(self.mask(image_bgr), cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)
        best = self._best_blob(contours, hierarchy)
        if best is None:
            return None
        index, area = best
        blob = contours[index]
        height, width = image_bgr.shape[:2]
        dot = _dot_centre(contours, hierarchy[0], index, area)
        if _touches_border(blob, width, height):
            return _partial_detection(blob, area, dot, width, height)
        m = cv2.moments(blob)
        u, v = dot if dot is not None else (m["m10"] / m["m00"], m["m01"] / m["m00"])
        return PadDetection(float(u), float(v), math.sqrt(area / math.pi) + _EDGE_HALF_PX, False)

    def _best_blob(self, contours, hierarchy) -> tuple[int, float] | None:
        """Index and area of the largest outer contour that is big and solid enough."""
        if hierarchy is None:
            return None
        best: tuple[int, float] | None = None
        for i, links in enumerate(hierarchy[0]):
            if links[3] != -1:
                continue  # a hole, not an outer boundary
            area = cv2.contourArea(contours[i])
            if area < self.cfg.min_area_px or (best is not None and area <= best[1]):
                continue
            hull_area = cv2.contourArea(cv2.convexHull(contours[i]))
            if hull_area > 0 and area / hull_area >= self.cfg.min_solidity:
                best = (i, area)
        return best


def _dot_centre(contours, links: np.ndarray, parent: int, parent_area: float) -> tuple[float, float] | None:
    """Centroid of the largest hole of the blob if its size fits the centre dot."""
    best, best_area = None, 0.0
    child = links[parent][2]
    while child != -1:
        area = cv2.contourArea(contours[child])
        if area > best_area:
            best, best_area = child, area
        child = links[child][0]
    if best is None:
        return None
    ratio = best_area / max(parent_area, 1e-9)
    if not (_DOT_AREA_RATIO[0] <= ratio <= _DOT_AREA_RATIO[1]):
        return None
    m = cv2.moments(contours[best])
    if m["m00"] <= 0:
        return None
    return m["m10"] / m["m00"], m["m01"] / m["m00"]


def _touches_border(contour: np.ndarray, width: int, height: int) -> bool:
    x, y, w, h = cv2.boundingRect(contour)
    return x <= 0 or y <= 0 or x + w >= width or y + h >= height


def _partial_detection(blob, area: float, dot, width: int, height: int) -> PadDetection:
    """A pad cut by the border: fit a circle to the rim inside the image."""
    pts = blob[:, 0, :].astype(float)
    inside = (pts[:, 0] > 0) & (pts[:, 0] < width - 1) & (pts[:, 1] > 0) & (pts[:, 1] < height - 1)
    rim = inside & _on_convex_rim(blob)
    fit = fit_circle(pts[rim]) if rim.sum() >= _MIN_ARC_POINTS else None
    area_radius = math.sqrt(area / math.pi)
    if fit is not None and not (0.9 * area_radius <= fit[2] <= _MAX_FIT_RADIUS_IMAGES * max(width, height)):
        fit = None  # an arc too straight or too noisy to trust: the visible area is safer
    if fit is None:
        m = cv2.moments(blob)
        centre = dot or (m["m10"] / m["m00"], m["m01"] / m["m00"])
        return PadDetection(float(centre[0]), float(centre[1]), area_radius + _EDGE_HALF_PX, True)
    cu, cv, radius = fit
    if dot is not None:
        cu, cv = dot
    return PadDetection(float(cu), float(cv), float(radius) + _EDGE_HALF_PX, True)


def _on_convex_rim(contour: np.ndarray) -> np.ndarray:
    """Which contour points lie on the blob's convex outline: not in a notch, such as the white
    dot's edge when the dot is cut by the image border and so joins the outer contour."""
    keep = np.ones(len(contour), bool)
    if len(contour) < 4:
        return keep
    hull = cv2.convexHull(contour, returnPoints=False)
    hull = np.sort(hull.reshape(-1))[:, None]  # convexityDefects wants monotonic hull indices
    try:
        defects = cv2.convexityDefects(contour, hull)
    except cv2.error:  # self-intersecting digitised outlines; keep every point
        return keep
    for start, end, _, depth in (defects.reshape(-1, 4) if defects is not None else ()):
        if depth / 256.0 > _NOTCH_DEPTH_PX:
            if start < end:
                keep[start + 1:end] = False
            else:
                keep[start + 1:] = False
                keep[:end] = False
    return keep


def fit_circle(points: np.ndarray) -> tuple[float, float, float] | None:
    """Least-squares (Kasa) circle through ``(N, 2)`` points; None if they are nearly collinear."""
    x, y = points[:, 0], points[:, 1]
    mx, my = x.mean(), y.mean()
    a = np.column_stack([x - mx, y - my, np.ones_like(x)])
    b = (x - mx) ** 2 + (y - my) ** 2
    sol, _, rank, sv = np.linalg.lstsq(a, b, rcond=None)
    if rank < 3 or sv[-1] < 1e-6 * sv[0]:
        return None
    cu, cv = sol[0] / 2, sol[1] / 2
    r2 = sol[2] + cu**2 + cv**2
    if r2 <= 0:
        return None
    return float(cu + mx), float(cv + my), math.sqrt(r2)


ReferenceRenderer = CameraRenderer
ReferenceDetector = PadDetector
