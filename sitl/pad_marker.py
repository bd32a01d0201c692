"""The ArUco board on the pad: its layout (shared by the renderer and the companion's detector)
and its drawing into the roof texture.

Why these markers: one marker size cannot be read from the start height down to touchdown with
a 320x240, 90 degree camera (about 160 px per metre at 1 m, 20 at 8 m; a 4x4 ArUco marker needs
about 3 px per cell, and the whole marker must be in view). So the board nests three sizes
around the pad's centre, all from ``DICT_4X4_50``:

- id 0, 0.15 m, centred on the pad: in view down to about 0.1 m above it (touchdown);
- ids 1-4, 0.69 m, a pinwheel around it: read from about 1 m to 6 m;
- ids 5-6, 0.93 m, north and south of the pad on the roof: read up to about 8 m (the start).

Pad frame: origin at the pad's centre on the roof, x north, y east, z down (the roof's own axes:
the ground vehicle drives without turning). Every size and offset is a whole number of roof
texels (2.5 mm), and every marker a whole number of texels per cell, so the drawn board is
exactly the one described here.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

DICTIONARY = cv2.aruco.DICT_4X4_50
CELLS = 6  # a 4x4 marker plus its one-cell black border
WHITE = (255, 255, 255)
TEXEL_M = 0.0025  # the roof texture's texel (sitl/camera.py _ROOF_TEXEL_M)
QUIET_TEXELS = 30  # white around the board: ArUco finds a marker by its dark border on light
# In texels from the pad centre: half the centre marker, the gaps, the ring and outer sizes.
_CENTRE_HALF, _RING_GAP, _RING = 30, 36, 276
_OUTER_GAP, _OUTER = 36, 372


@dataclass(frozen=True)
class Marker:
    """One marker: its id and the pad-frame (north, east) of its top-left corner and its size.
    Drawn upright in the texture: its top edge faces north, its left edge west."""

    marker_id: int
    north_m: float  # of the top-left (north-west) corner
    east_m: float
    size_m: float

    def corners_m(self) -> np.ndarray:
        """(4, 3) pad-frame corners in OpenCV's order: top-left, top-right, bottom-right,
        bottom-left of the marker image (north-west, north-east, south-east, south-west)."""
        n, e, s = self.north_m, self.east_m, self.size_m
        return np.array([[n, e, 0.0], [n, e + s, 0.0], [n - s, e + s, 0.0], [n - s, e, 0.0]], np.float32)


def _layout() -> tuple[Marker, ...]:
    """The markers in texels converted to metres (east, north upright; see the module doc)."""
    a, g, s = _CENTRE_HALF, _RING_GAP, _RING
    # A ring marker spans east [-a, -a + s], north [a + g, a + g + s]; the others are it turned
    # by 90, 180 and 270 degrees about the centre: a pinwheel with gaps g everywhere.
    ring_boxes = [(-a, a + g + s), (a + g, a), (a - s, -a - g), (-a - g - s, -a + s)]  # (west edge, north edge)
    markers = [Marker(0, a * TEXEL_M, -a * TEXEL_M, 2 * a * TEXEL_M)]
    markers += [Marker(i + 1, north * TEXEL_M, west * TEXEL_M, s * TEXEL_M) for i, (west, north) in enumerate(ring_boxes)]
    reach = a + g + s + _OUTER_GAP  # the outer markers start beyond the ring
    markers += [
        Marker(5, (reach + _OUTER) * TEXEL_M, -_OUTER / 2 * TEXEL_M, _OUTER * TEXEL_M),
        Marker(6, -reach * TEXEL_M, -_OUTER / 2 * TEXEL_M, _OUTER * TEXEL_M),
    ]
    return tuple(markers)


MARKERS: tuple[Marker, ...] = _layout()


def board_half_extent_m() -> tuple[float, float]:
    """(north, east) half-size of the board with its white quiet zone: what the roof must hold."""
    corners = np.concatenate([m.corners_m() for m in MARKERS])
    quiet = QUIET_TEXELS * TEXEL_M
    return float(np.abs(corners[:, 0]).max() + quiet), float(np.abs(corners[:, 1]).max() + quiet)


@lru_cache(maxsize=1)
def dictionary() -> cv2.aruco.Dictionary:
    return cv2.aruco.getPredefinedDictionary(DICTIONARY)


def board() -> cv2.aruco.Board:
    """The layout as an OpenCV board (object points in the pad frame, metres)."""
    ids = np.array([m.marker_id for m in MARKERS], np.int32)
    return cv2.aruco.Board([m.corners_m() for m in MARKERS], dictionary(), ids)


def check_fits(length_m: float, width_m: float) -> None:
    """The board must lie on the roof with its quiet zone; ValueError saying what to change."""
    half_n, half_e = board_half_extent_m()
    if half_n > length_m / 2 or half_e > width_m / 2:
        raise ValueError(
            f"the ArUco board needs a roof of at least {2 * half_n:.2f} m x {2 * half_e:.2f} m "
            f"(north x east), the ground vehicle's is {length_m} m x {width_m} m; enlarge "
            "[sitl.world] vehicle_length_m / vehicle_width_m or set [sitl.camera] pad_marker = \"none\""
        )


def draw_board(texture: np.ndarray) -> None:
    """Draw the board, centred, into a BGR top-down roof texture (row 0 north, column 0 west,
    texels of :data:`TEXEL_M`) in place: a white square, then each marker pixel-exact."""
    rows, cols = texture.shape[:2]
    centre_row, centre_col = (rows - 1) / 2.0, (cols - 1) / 2.0

    def texel(north_m: float, east_m: float) -> tuple[int, int]:
        """The (row, col) of the texel whose north-west corner is at this pad-frame point."""
        return int(round(centre_row - north_m / TEXEL_M + 0.5)), int(round(centre_col + east_m / TEXEL_M + 0.5))

    half_n, half_e = board_half_extent_m()
    r0, c0 = texel(half_n, -half_e)
    r1, c1 = texel(-half_n, half_e)
    texture[max(r0, 0):r1, max(c0, 0):c1] = WHITE
    for marker in MARKERS:
        side = int(round(marker.size_m / TEXEL_M))
        image = cv2.aruco.generateImageMarker(dictionary(), marker.marker_id, side, borderBits=1)
        row, col = texel(marker.north_m, marker.east_m)
        texture[row:row + side, col:col + side] = image[:, :, None]
