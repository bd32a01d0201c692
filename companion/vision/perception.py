"""The hand-crafted landing-pad detector: colour, then shape, then the centre mark.

The pad (docs/camera.md) is a saturated magenta disc with a white centre dot on a grey roof.
1. Colour: pixels whose HSV hue is magenta, saturation above about the pad/roof midpoint and
   value above a floor. Hue and saturation do not change when the light gets brighter or darker,
   and a threshold at the midpoint keeps a blurred edge where the sharp edge was.
2. Shape: the largest convex (solid) blob is the pad; its area gives the radius.
3. Centre: the white dot's hole in the blob, when visible, because the centroid of a circle seen
   obliquely is not the image of its centre (the error grows with (radius / distance)^2 and the
   dot is 5x smaller than the disc); otherwise the blob's centroid.

A pad cut by the image border is reported with ``partial=True``: radius (and centre, if the dot
is not seen) come from a circle fitted to the rim that is inside the image, so the centre can
lie outside the image.
"""

from __future__ import annotations

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
