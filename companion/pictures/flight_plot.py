"""``flight.png``: every episode's track from above, coloured by who flew, with its touchdown."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from companion.pictures.recorder import EpisodeTrack

COLOURS = {"person": "#ef6c00", "policy": "#0288d1", "hold": "#c62828"}


def _segments(track: EpisodeTrack) -> list[tuple[str, list[float], list[float]]]:
    """Runs of consecutive points flown by the same one, each sharing its first point with the
    run before (so the line is unbroken)."""
    runs: list[tuple[str, list[float], list[float]]] = []
    prev = None
    for p in track.points:
        if not runs or runs[-1][0] != p.who:
            runs.append((p.who, [prev.east_m] if prev else [], [prev.north_m] if prev else []))
        runs[-1][1].append(p.east_m)
        runs[-1][2].append(p.north_m)
        prev = p
    return runs


def plot_flight(tracks: Sequence[EpisodeTrack], outcomes: dict[int, tuple[str, bool | None]],
                pad_ne_m: tuple[float, float], pad_radius_m: float, path: Path, title: str = "") -> Path:
    """Write the top view (east right, north up) to ``path``; ``outcomes``: episode -> (outcome, success).

    matplotlib is the ``[train]`` extra: without it (the lean install) OpenCV draws the picture."""
    try:
        import matplotlib
    except ImportError:
        from companion.pictures.flight_cv import draw_flight

        return draw_flight(tracks, outcomes, pad_ne_m, pad_radius_m, path,
                           title or f"{len(tracks)} episodes from above", COLOURS)

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D
    from matplotlib.patches import Circle

    fig, ax = plt.subplots(figsize=(6.4, 6.4), dpi=110)
    ax.add_patch(Circle((pad_ne_m[1], pad_ne_m[0]), pad_radius_m, color="#d028d2", alpha=0.6, zorder=1))
    for track in tracks:
        for who, east, north in _segments(track):
            ax.plot(east, north, color=COLOURS.get(who, "grey"), linewidth=1.2, alpha=0.8, zorder=2)
        if track.points:
            ax.plot(track.points[0].east_m, track.points[0].north_m, "o", color="grey", markersize=3, zorder=3)
            outcome, success = outcomes.get(track.episode, ("", None))
            if outcome == "touchdown":
                last = track.points[-1]
                ax.plot(last.east_m, last.north_m, "X", markersize=9, zorder=4,
                        color="#2e7d32" if success else "#b71c1c", markeredgecolor="black", markeredgewidth=0.5)
    handles = [Line2D([], [], color=c, label=w) for w, c in COLOURS.items()] + [
        Line2D([], [], marker="X", linestyle="", color="#2e7d32", label="touchdown on the pad"),
        Line2D([], [], marker="X", linestyle="", color="#b71c1c", label="touchdown off the pad"),
        Line2D([], [], marker="o", linestyle="", color="grey", label="start")]
    ax.legend(handles=handles, loc="upper right", fontsize=8)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("east (m)")
    ax.set_ylabel("north (m)")
    ax.grid(alpha=0.3)
    ax.set_title(title or f"{len(tracks)} episodes from above")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return path
