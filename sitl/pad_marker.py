"""The ArUco boards on the pad: their layouts (shared by the renderer and the companion's
detector) and their drawing into the roof texture.

Why these markers: one marker size cannot be read from the start height down to touchdown with
a 320x240, 90 degree camera (about 160 px per metre at 1 m, 20 at 8 m; a 4x4 ArUco marker needs
about 3 px per cell, and the whole marker must be in view). So each board nests three sizes
around the pad's centre, all from ``DICT_4X4_50``. Two boards (``[sitl.camera] pad_marker``):

``aruco``, black on a white square over the pad (it hides the colour disc the learned policies
see through):

- id 0, 0.15 m, centred on the pad: in view down to about 0.1 m above it (touchdown);
- ids 1-4, 0.69 m, a pinwheel around it: read from about 1 m to 6 m;
- ids 5-6, 0.93 m, north and south of the pad on the roof: read up to about 8 m (the start).

``aruco-disc``, drawn so that the colour detector still sees the plain pad: the disc, its rim and
its white dot stay where they are, and only marker ink is added inside them:

- id 7, 0.105 m, black ink in the white centre dot (the dot's hole in the colour mask stays the
  dot: black is not magenta either);
- ids 8-11, 0.285 m, a pinwheel of dark-magenta ink on the magenta disc, clear of the dot and of
  the rim (dark magenta is magenta to the colour detector and dark to the grey image ArUco reads);
- ids 12-13, 0.93 m, black on white north and south of the disc on the roof, as in ``aruco``.

Pad frame: origin at the pad's centre on the roof, x north, y east, z down (the roof's own axes:
the ground vehicle drives without turning). Every size and offset is a whole number of roof
texels (2.5 mm), and every marker a whole number of texels per cell, so the drawn board is
exactly the one described here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Literal

import cv2
import numpy as np

DICTIONARY = cv2.aruco.DICT_4X4_50
CELLS = 6  # a 4x4 marker plus its one-cell black border
WHITE = (255, 255, 255)
BLACK = (0, 0, 0)
# Dark magenta (BGR): OpenCV hue about 154, saturation 255, value 70, so the colour detector's
# mask (hue 135-170, saturation >= 110, value >= 35) keeps it, and grey about 28 against the pad
# magenta's 113 for ArUco. Any blend of it with the pad's magenta is magenta too.
DARK_MAGENTA = (60, 0, 70)
TEXEL_M = 0.0025  # the roof texture's texel (sitl/camera.py _ROOF_TEXEL_M)
QUIET_TEXELS = 30  # white around a marker on the roof: ArUco finds a marker by its dark border on light
CLEARANCE_M = 0.02  # light around a marker inked into the dot or the disc, up to their edges

Surface = Literal["white", "dot", "disc"]


@dataclass(frozen=True)
class Marker:
    """One marker: its id, the pad-frame (north, east) of its top-left corner and its size, and
    what it is printed on: its own white square (``white``), the pad's white dot or its magenta
    disc (inked onto them, their colour as the marker's light cells).
    Drawn upright in the texture: its top edge faces north, its left edge west."""

    marker_id: int
    north_m: float  # of the top-left (north-west) corner
    east_m: float
    size_m: float
    surface: Surface = "white"

    def corners_m(self) -> np.ndarray:
        """(4, 3) pad-frame corners in OpenCV's order: top-left, top-right, bottom-right,
        bottom-left of the marker image (north-west, north-east, south-east, south-west)."""
        n, e, s = self.north_m, self.east_m, self.size_m
        return np.array([[n, e, 0.0], [n, e + s, 0.0], [n - s, e + s, 0.0], [n - s, e, 0.0]], np.float32)

    @property
    def ink_bgr(self) -> tuple[int, int, int]:
        return DARK_MAGENTA if self.surface == "disc" else BLACK

    def reach_m(self) -> float:
        """Distance from the pad's centre to the marker's farthest corner."""
        return float(np.hypot(*self.corners_m()[:, :2].T).max())

    def nearest_m(self) -> float:
        """Distance from the pad's centre to the marker's nearest point."""
        n0, n1 = self.north_m - self.size_m, self.north_m
        e0, e1 = self.east_m, self.east_m + self.size_m
        return math.hypot(max(n0, 0.0, -n1), max(e0, 0.0, -e1))


def _pinwheel(first_id: int, inner_half: int, gap: int, side: int, surface: Surface) -> list[Marker]:
    """Four markers of ``side`` texels around a centre square of half-size ``inner_half``: one
    spans east [-a, -a + s], north [a + g, a + g + s]; the others are it turned by 90, 180 and 270
    degrees about the centre, so every gap between them is ``gap``."""
    a, g, s = inner_half, gap, side
    boxes = [(-a, a + g + s), (a + g, a), (a - s, -a - g), (-a - g - s, -a + s)]  # (west edge, north edge)
    return [Marker(first_id + i, north * TEXEL_M, west * TEXEL_M, s * TEXEL_M, surface)
            for i, (west, north) in enumerate(boxes)]


def _outer_pair(first_id: int, start: int, side: int) -> list[Marker]:
    """Two markers of ``side`` texels north and south of the pad, ``start`` texels from its centre."""
    return [
        Marker(first_id, (start + side) * TEXEL_M, -side / 2 * TEXEL_M, side * TEXEL_M),
        Marker(first_id + 1, -start * TEXEL_M, -side / 2 * TEXEL_M, side * TEXEL_M),
    ]


def _aruco() -> tuple[Marker, ...]:
    """The first board, in texels: centre half 30, ring gap 36 and side 276, outer gap 36 and
    side 372, all on one white square."""
    centre_half, ring_gap, ring, outer_gap, outer = 30, 36, 276, 36, 372
    markers = [Marker(0, centre_half * TEXEL_M, -centre_half * TEXEL_M, 2 * centre_half * TEXEL_M)]
    markers += _pinwheel(1, centre_half, ring_gap, ring, "white")
    markers += _outer_pair(5, centre_half + ring_gap + ring + outer_gap, outer)
    return tuple(markers)


def _aruco_disc() -> tuple[Marker, ...]:
    """The board that leaves the colour pad (0.5 m disc, 0.1 m dot) in view, in texels: a centre
    marker of 42 (7 per cell) in the 40-texel dot, a ring of 114 (19 per cell) around the dot's
    square with gaps of 16, reaching 0.464 m, and the outer pair of 372 from 236 (beyond the
    disc's 200 and its quiet zone)."""
    centre = 42
    markers = [Marker(7, centre / 2 * TEXEL_M, -centre / 2 * TEXEL_M, centre * TEXEL_M, "dot")]
    markers += _pinwheel(8, 40, 16, 114, "disc")
    markers += _outer_pair(12, 236, 372)
    return tuple(markers)


@dataclass(frozen=True)
class Layout:
    """A board: its markers, and whether one white square lies under all of them, over the pad
    (the first board) or each roof marker has its own, clear of the pad (a board inked into it)."""

    markers: tuple[Marker, ...]
    covers_pad: bool


LAYOUTS: dict[str, Layout] = {"aruco": Layout(_aruco(), covers_pad=True),
                              "aruco-disc": Layout(_aruco_disc(), covers_pad=False)}
BOARDS: tuple[str, ...] = tuple(LAYOUTS)


def markers(name: str) -> tuple[Marker, ...]:
    """The markers of the board ``name`` (one of :data:`BOARDS`); ValueError naming them."""
    return layout(name).markers


def layout(name: str) -> Layout:
    """The board ``name`` (one of :data:`BOARDS`); ValueError naming them."""
    try:
        return LAYOUTS[name]
    except KeyError:
        raise ValueError(f"no ArUco board {name!r}: the boards are {', '.join(BOARDS)}") from None


def _white_boxes(name: str) -> list[tuple[float, float, float, float]]:
    """(north max, west, north min, east) of each white square the board prints on the roof,
    quiet zone included: one under the whole board that covers the pad, one per roof marker otherwise."""
    quiet = QUIET_TEXELS * TEXEL_M
    on_white = [m for m in markers(name) if m.surface == "white"]
    if layout(name).covers_pad:
        corners = np.concatenate([m.corners_m() for m in on_white])
        half_n, half_e = np.abs(corners[:, 0]).max() + quiet, np.abs(corners[:, 1]).max() + quiet
        return [(float(half_n), float(-half_e), float(-half_n), float(half_e))]
    return [(m.north_m + quiet, m.east_m - quiet, m.north_m - m.size_m - quiet, m.east_m + m.size_m + quiet)
            for m in on_white]


def board_half_extent_m(name: str = "aruco") -> tuple[float, float]:
    """(north, east) half-size of the board with its white quiet zones: what the roof must hold."""
    boxes = np.array(_white_boxes(name))
    return float(np.abs(boxes[:, [0, 2]]).max()), float(np.abs(boxes[:, [1, 3]]).max())


@lru_cache(maxsize=1)
def dictionary() -> cv2.aruco.Dictionary:
    return cv2.aruco.getPredefinedDictionary(DICTIONARY)


def board(name: str = "aruco") -> cv2.aruco.Board:
    """The layout as an OpenCV board (object points in the pad frame, metres)."""
    layout = markers(name)
    ids = np.array([m.marker_id for m in layout], np.int32)
    return cv2.aruco.Board([m.corners_m() for m in layout], dictionary(), ids)


def check_fits(name: str, length_m: float, width_m: float, pad_radius_m: float, dot_radius_m: float) -> None:
    """The board must lie on the roof with its quiet zones, and a board inked into the pad must
    find the dot and the disc it is printed on; ValueError saying what to change."""
    half_n, half_e = board_half_extent_m(name)
    if half_n > length_m / 2 or half_e > width_m / 2:
        raise ValueError(
            f"the ArUco board {name!r} needs a roof of at least {2 * half_n:.2f} m x {2 * half_e:.2f} m "
            f"(north x east), the ground vehicle's is {length_m} m x {width_m} m; enlarge "
            "[sitl.world] vehicle_length_m / vehicle_width_m or set [sitl.camera] pad_marker = \"none\""
        )
    problems = [_surface_problem(name, m, pad_radius_m, dot_radius_m) for m in markers(name)]
    problems = [p for p in problems if p]
    if problems:
        raise ValueError(f"the ArUco board {name!r} does not fit the pad: " + "; ".join(problems))


def _surface_problem(name: str, m: Marker, pad_radius_m: float, dot_radius_m: float) -> str:
    """What keeps marker ``m`` off the surface it is printed on ('' when nothing): a marker in the
    dot must lie inside it, one on the disc between dot and rim, and a roof marker's white square
    of a board inked into the pad must leave the disc alone (a board that covers the pad may)."""
    clear = CLEARANCE_M
    if m.surface == "dot" and m.reach_m() + clear > dot_radius_m:
        return f"marker {m.marker_id} lies in the white dot: [sitl.camera] pad_dot_radius_m >= {m.reach_m() + clear:.3f} needed, it is {dot_radius_m}"
    if m.surface == "disc" and m.reach_m() + clear > pad_radius_m:
        return f"marker {m.marker_id} lies on the disc: [sitl.world] pad_radius_m >= {m.reach_m() + clear:.3f} needed, it is {pad_radius_m}"
    if m.surface == "disc" and m.nearest_m() - clear < dot_radius_m:
        return f"marker {m.marker_id} lies outside the dot: [sitl.camera] pad_dot_radius_m <= {m.nearest_m() - clear:.3f} needed, it is {dot_radius_m}"
    quiet = QUIET_TEXELS * TEXEL_M
    if m.surface == "white" and not layout(name).covers_pad and m.nearest_m() - quiet < pad_radius_m:
        return f"marker {m.marker_id}'s white square would cover the disc: [sitl.world] pad_radius_m <= {m.nearest_m() - quiet:.3f} needed, it is {pad_radius_m}"
    return ""

def draw_board(name: str, texture: np.ndarray) -> None:
    """Draw the board, centred, into a BGR top-down roof texture (row 0 north, column 0 west,
    texels of :data:`TEXEL_M`) in place: its white squares, then each marker's dark cells in its
    ink, pixel-exact (light cells keep what is beneath: white, or the pad's dot or disc)."""
    rows, cols = texture.shape[:2]
    centre_row, centre_col = (rows - 1) / 2.0, (cols - 1) / 2.0

    def texel(north_m: float, east_m: float) -> tuple[int, int]:
        """The (row, col) of the texel whose north-west corner is at this pad-frame point."""
        return int(round(centre_row - north_m / TEXEL_M + 0.5)), int(round(centre_col + east_m / TEXEL_M + 0.5))

    for north, west, south, east in _white_boxes(name):
        r0, c0 = texel(north, west)
        r1, c1 = texel(south, east)
        texture[max(r0, 0):r1, max(c0, 0):c1] = WHITE
    for marker in markers(name):
        side = int(round(marker.size_m / TEXEL_M))
        image = cv2.aruco.generateImageMarker(dictionary(), marker.marker_id, side, borderBits=1)
        row, col = texel(marker.north_m, marker.east_m)
        texture[row:row + side, col:col + side][image == 0] = marker.ink_bgr
