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
from functools import lru_cache

import cv2
import numpy as np

from companion.config import PerceptionConfig
from companion.msg.pad import PadDetection

_EDGE_HALF_PX = 0.5  # contour points are boundary pixel centres: the edge is half a pixel further
_MIN_ARC_POINTS = 12
_NOTCH_DEPTH_PX = 1.5  # deeper dents in the outline are not the rim
_MAX_FIT_RADIUS_IMAGES = 4.0  # a fitted rim larger than this many image sizes is not the pad
_DOT_AREA_RATIO = (0.005, 0.2)  # (dot / disc) area; the marking's is 0.04


class PadDetector:
    """Stateless: each frame is judged alone, so a missed frame never poisons the next."""

    def __init__(self, cfg: PerceptionConfig | None = None) -> None:
        cfg = cfg or PerceptionConfig()
        self.cfg = cfg
        self._lo = np.array([cfg.hue_min, cfg.saturation_min, cfg.value_min], np.uint8)
        self._hi = np.array([cfg.hue_max, 255, 255], np.uint8)
        self._limits: dict[int, np.ndarray] = {}  # per image size: the byte limits of _candidate_box

    def mask(self, image_bgr: np.ndarray) -> np.ndarray:
        """Binary mask (0/255) of pad-coloured pixels.

        The HSV threshold itself, computed only inside the bounding box of the pixels that pass a
        cheaper test every pad colour passes (see :func:`_green_margin`): outside it the mask is
        0 either way, so the mask is the one of the whole image, bit for bit."""
        return self._mask(image_bgr)[0]

    def _mask(self, image_bgr: np.ndarray) -> tuple[np.ndarray, tuple[int, int, int, int] | None]:
        """The mask and a box ``(x0, y0, x1, y1)`` outside which it is 0 (None: 0 everywhere)."""
        if image_bgr.ndim != 3 or image_bgr.shape[2] != 3 or image_bgr.dtype != np.uint8:
            raise ValueError(f"expected an HxWx3 uint8 BGR image, got {image_bgr.dtype} {image_bgr.shape}")
        height, width = image_bgr.shape[:2]
        margin = _green_margin(self._lo.tobytes(), self._hi.tobytes())
        if margin is None or not image_bgr.flags.c_contiguous or image_bgr.size < 3:  # no pre-test
            return cv2.inRange(cv2.cvtColor(image_bgr, cv2.COLOR_BGR2HSV), self._lo, self._hi), (0, 0, width, height)
        box = self._candidate_box(image_bgr, margin)
        mask = np.zeros((height, width), np.uint8)
        if box is not None:
            x0, y0, x1, y1 = box
            hsv = cv2.cvtColor(image_bgr[y0:y1, x0:x1], cv2.COLOR_BGR2HSV)
            cv2.inRange(hsv, self._lo, self._hi, dst=mask[y0:y1, x0:x1])
        return mask, box

    def _candidate_box(self, image_bgr: np.ndarray, margin: int) -> tuple[int, int, int, int] | None:
        """``(x0, y0, x1, y1)`` holding every pixel with ``min(B, R) - G >= margin`` (a necessary
        condition for the HSV box, see :func:`_green_margin`), or None if there is none.

        On the interleaved bytes: ``min(flat[k], flat[k+2])`` is ``min(B, R)`` at the first byte
        of each pixel, and adding a per-byte limit (``margin - 1`` there, 255 elsewhere, which
        saturates) before a saturating subtraction leaves non-zero bytes exactly at candidates.
        Three passes of integer SIMD instead of the HSV conversion and a 3-channel inRange."""
        height, width = image_bgr.shape[:2]
        flat = image_bgr.reshape(-1)  # a C-contiguous image
        n = flat.size
        limit = self._limits.get(n)
        if limit is None:
            limit = np.full(n - 2, 255, np.uint8)
            limit[0::3] = margin - 1
            self._limits = {**self._limits, n: limit}  # replaced, not mutated: safe across threads
        low = cv2.min(flat[:-2], flat[2:])
        limit_sum = cv2.add(flat[1:-1], limit)
        hits = np.empty(n, np.uint8)
        hits[-2:] = 0
        cv2.subtract(low, limit_sum, dst=hits[:-2])
        if not cv2.hasNonZero(hits):
            return None
        rows = hits.reshape(height, 3 * width)
        if height % 4 == 0:  # rows in fours (a max of row pairs, twice): a quarter to scan
            pairs = cv2.max(rows[0::2], rows[1::2])
            x, y, w, h = cv2.boundingRect(cv2.max(pairs[0::2], pairs[1::2]))
            y, h = 4 * y, 4 * h
        else:
            x, y, w, h = cv2.boundingRect(rows)
        return x // 3, y, (x + w - 1) // 3 + 1, y + h

    def detect(self, image_bgr: np.ndarray) -> PadDetection | None:
        """The pad, or None when no pad-coloured convex blob of the minimum size is in view."""
        mask, box = self._mask(image_bgr)
        if box is None:
            return None  # not one pixel passes even the pre-test
        # The contours of the box grown by a pixel (zeros there, or the image's own border), put
        # back with ``offset``, are those of the whole mask, in the same order.
        height, width = image_bgr.shape[:2]
        x0, y0 = max(box[0] - 1, 0), max(box[1] - 1, 0)
        roi = mask[y0:min(box[3] + 1, height), x0:min(box[2] + 1, width)]
        contours, hierarchy = cv2.findContours(roi, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE, offset=(x0, y0))
        best = self._best_blob(contours, hierarchy)
        if best is None:
            return None
        index, area = best
        blob = contours[index]
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
    if defects is None:
        return keep
    defects = defects.reshape(-1, 4)
    deep = defects[defects[:, 3] > _NOTCH_DEPTH_PX * 256.0]  # depth in 1/256 px; the rest is rim
    for start, end, _, _ in deep:
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


@lru_cache(maxsize=8)
def _green_margin(lo: bytes, hi: bytes) -> int | None:
    """The largest ``m`` with ``min(B, R) - G >= m`` for every colour whose HSV lies in
    ``[lo, hi]`` (magenta: green is well below blue and red), found by converting all 2^24
    colours with this OpenCV (0.1 s, once per process and thresholds); None if ``m < 1`` (then
    the test would keep every pixel)."""
    lo_a, hi_a = np.frombuffer(lo, np.uint8), np.frombuffer(hi, np.uint8)
    levels = np.arange(256, dtype=np.int16)
    low = np.minimum.outer(levels, levels)  # min(B, R) over a (B, R) plane
    plane = np.empty((256, 256, 3), np.uint8)
    plane[..., 0] = levels[:, None]
    plane[..., 2] = levels[None, :]
    best = 256
    for green in range(256):
        plane[..., 1] = green
        inside = cv2.inRange(cv2.cvtColor(plane, cv2.COLOR_BGR2HSV), lo_a, hi_a) > 0
        if inside.any():
            best = min(best, int(low[inside].min()) - green)
    return best if 1 <= best <= 255 else None
