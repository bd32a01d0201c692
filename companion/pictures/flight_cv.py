"""``flight.png`` drawn with OpenCV, for installs without matplotlib (the lean flight runtime).

The same picture as :func:`companion.pictures.flight_plot.plot_flight` in fewer words: east to
the right, north up, equal scale, a 1 m grid, the pad, each track coloured by who flew, starts
as grey dots and touchdowns as crosses (green on the pad, red off it), a legend and a title.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from companion.pictures.recorder import EpisodeTrack

SIZE_PX = 704
MARGIN_PX = 48
GREY, GRID, INK = (128, 128, 128), (225, 225, 225), (40, 40, 40)
ON_PAD, OFF_PAD, PAD = (50, 125, 46), (28, 28, 183), (210, 40, 208)


def bgr(hex_colour: str) -> tuple[int, int, int]:
    """``#rrggbb`` as OpenCV's (blue, green, red)."""
    r, g, b = (int(hex_colour[i:i + 2], 16) for i in (1, 3, 5))
    return b, g, r


class _View:
    """Metres (east, north) to pixels: one scale for both axes, north up."""

    def __init__(self, east: np.ndarray, north: np.ndarray) -> None:
        self.east0, self.north0 = float(east.min()), float(north.min())
        span = max(float(east.max()) - self.east0, float(north.max()) - self.north0, 1.0)
        self.px_per_m = (SIZE_PX - 2 * MARGIN_PX) / span

    def px(self, east_m: float, north_m: float) -> tuple[int, int]:
        return (round(MARGIN_PX + (east_m - self.east0) * self.px_per_m),
                round(SIZE_PX - MARGIN_PX - (north_m - self.north0) * self.px_per_m))


def _grid(img: np.ndarray, view: _View) -> None:
    for metre in range(int(np.floor(view.east0)) - 1, int(view.east0 + SIZE_PX / view.px_per_m) + 2):
        x = view.px(metre, view.north0)[0]
        cv2.line(img, (x, 0), (x, SIZE_PX), GRID, 1)
    for metre in range(int(np.floor(view.north0)) - 1, int(view.north0 + SIZE_PX / view.px_per_m) + 2):
        y = view.px(view.east0, metre)[1]
        cv2.line(img, (0, y), (SIZE_PX, y), GRID, 1)


def _legend(img: np.ndarray, colours: dict[str, str]) -> None:
    entries = [(bgr(c), who) for who, c in colours.items()]
    entries += [(ON_PAD, "touchdown on the pad"), (OFF_PAD, "touchdown off the pad"), (GREY, "start")]
    for i, (colour, label) in enumerate(entries):
        y = 44 + 18 * i
        cv2.line(img, (SIZE_PX - 210, y), (SIZE_PX - 190, y), colour, 3)
        cv2.putText(img, label, (SIZE_PX - 182, y + 5), cv2.FONT_HERSHEY_SIMPLEX, 0.42, INK, 1, cv2.LINE_AA)


def draw_flight(tracks: Sequence[EpisodeTrack], outcomes: dict[int, tuple[str, bool | None]],
                pad_ne_m: tuple[float, float], pad_radius_m: float, path: Path, title: str,
                colours: dict[str, str]) -> Path:
    """Write the top view to ``path`` (PNG); arguments as for ``plot_flight``."""
    points = [(p.east_m, p.north_m) for t in tracks for p in t.points]
    east = np.array([pad_ne_m[1] - pad_radius_m, pad_ne_m[1] + pad_radius_m] + [e for e, _ in points])
    north = np.array([pad_ne_m[0] - pad_radius_m, pad_ne_m[0] + pad_radius_m] + [n for _, n in points])
    view = _View(east, north)
    img = np.full((SIZE_PX, SIZE_PX, 3), 255, np.uint8)
    _grid(img, view)
    cv2.circle(img, view.px(pad_ne_m[1], pad_ne_m[0]), max(2, round(pad_radius_m * view.px_per_m)), PAD, -1, cv2.LINE_AA)
    for track in tracks:
        for a, b in zip(track.points, track.points[1:], strict=False):
            cv2.line(img, view.px(a.east_m, a.north_m), view.px(b.east_m, b.north_m), bgr(colours.get(b.who, "#808080")),
                     2, cv2.LINE_AA)
        if track.points:
            cv2.circle(img, view.px(track.points[0].east_m, track.points[0].north_m), 4, GREY, -1, cv2.LINE_AA)
            outcome, success = outcomes.get(track.episode, ("", None))
            if outcome == "touchdown":
                last = track.points[-1]
                cv2.drawMarker(img, view.px(last.east_m, last.north_m), ON_PAD if success else OFF_PAD,
                               cv2.MARKER_TILTED_CROSS, 16, 3, cv2.LINE_AA)
    _legend(img, colours)
    cv2.putText(img, title, (MARGIN_PX, 28), cv2.FONT_HERSHEY_SIMPLEX, 0.6, INK, 1, cv2.LINE_AA)
    cv2.putText(img, "east (m) ->   north (m) ^   grid 1 m", (MARGIN_PX, SIZE_PX - 14), cv2.FONT_HERSHEY_SIMPLEX,
                0.45, INK, 1, cv2.LINE_AA)
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), img):
        raise OSError(f"OpenCV could not write {path}")
    return path
