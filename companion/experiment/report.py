"""The grid's results as the paper shows them: a Markdown table beside its numbers, and plots.

Task completion is each final policy's success rate on the held-out starts, in percent;
a cell's mean and standard error (sample standard deviation / sqrt(n)) are over its trials
(participants x replicate seeds), as the paper's error bars are over its four participants.
Human samples are the observation-action pairs recorded in a trial's training.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

from companion.experiment.results import TrialResult

LABELS = {"int": "Int", "demo": "Demo", "col": "CoL"}
ORDER = ("int", "demo", "col")  # the paper's bar order
COLOURS = {"int": "#8da0cb", "demo": "#66c2a5", "col": "#fc8d62"}
PAPER_COMPLETION_PCT: dict[tuple[str, int], tuple[float, float]] = {
    ("col", 20): (90.25, 5.63), ("demo", 20): (76.25, 2.72),
    ("col", 8): (74.75, 9.38), ("demo", 8): (54.00, 8.95),
}
"""(condition, interactions) -> (mean, s.e.) reported in the paper's Results."""
PAPER_COL_SAMPLES_20 = (1574.5, 54.22)
PAPER_COL_FEWER_SAMPLES_PCT_20 = 37.79
PAPER_DEMO_SAMPLES_20 = PAPER_COL_SAMPLES_20[0] / (1.0 - PAPER_COL_FEWER_SAMPLES_PCT_20 / 100.0)
"""Not printed in the paper: implied by CoL's 1574.5 samples being 37.79 % fewer."""


def mean_se(values: Sequence[float]) -> tuple[float, float | None]:
    """Mean and standard error of the mean; no s.e. from a single value."""
    if not values:
        raise ValueError("mean_se needs at least one value")
    mean = statistics.fmean(values)
    if len(values) < 2:
        return mean, None
    return mean, statistics.stdev(values) / math.sqrt(len(values))


@dataclass(frozen=True)
class Cell:
    """One condition at one interaction count, over its trials."""

    condition: str
    interactions: int
    n: int
    completion_pct: tuple[float, float | None]
    samples: tuple[float, float | None]


def summarise(results: Iterable[TrialResult]) -> list[Cell]:
    """Cells of the finished trials, by interaction count then the paper's condition order."""
    groups: dict[tuple[str, int], list[TrialResult]] = {}
    for r in results:
        if r.status == "ok":
            groups.setdefault((r.trial.condition, r.trial.interactions), []).append(r)
    keys = sorted(groups, key=lambda k: (k[1], ORDER.index(k[0])))
    return [Cell(c, n, len(groups[(c, n)]),
                 mean_se([r.completion_pct for r in groups[(c, n)]]),
                 mean_se([float(r.human_samples) for r in groups[(c, n)]])) for c, n in keys]


def _fmt(value: tuple[float, float | None], digits: int = 2) -> str:
    mean, se = value
    return f"{mean:.{digits}f}" if se is None else f"{mean:.{digits}f} ± {se:.{digits}f}"


def _paper_completion(cell: Cell) -> str:
    paper = PAPER_COMPLETION_PCT.get((cell.condition, cell.interactions))
    return "" if paper is None else _fmt(paper)


def _paper_samples(cell: Cell) -> str:
    if cell.interactions != 20:
        return ""
    if cell.condition == "col":
        return _fmt(PAPER_COL_SAMPLES_20, 1)
    return f"≈ {PAPER_DEMO_SAMPLES_20:.0f} (implied)" if cell.condition == "demo" else ""


def markdown(cells: Sequence[Cell]) -> str:
    """The report: completion and samples per cell, then CoL against Demo."""
    lines = ["## Task completion (%) and human samples, mean ± s.e. over trials", "",
             "| interactions | condition | trials | completion % | paper | human samples | paper |",
             "| ---: | --- | ---: | ---: | ---: | ---: | ---: |"]
    for c in cells:
        lines.append(f"| {c.interactions} | {LABELS[c.condition]} | {c.n} | {_fmt(c.completion_pct)} | "
                     f"{_paper_completion(c)} | {_fmt(c.samples, 1)} | {_paper_samples(c)} |")
    lines += ["", *_col_vs_demo(cells)]
    return "\n".join(lines) + "\n"


def _col_vs_demo(cells: Sequence[Cell]) -> list[str]:
    """CoL minus Demo in completion points, and CoL's sample saving, where both ran."""
    by_key = {(c.condition, c.interactions): c for c in cells}
    rows = []
    for n in sorted({c.interactions for c in cells}):
        col, demo = by_key.get(("col", n)), by_key.get(("demo", n))
        if col is None or demo is None:
            continue
        gain = col.completion_pct[0] - demo.completion_pct[0]
        fewer = 100.0 * (1.0 - col.samples[0] / demo.samples[0]) if demo.samples[0] else math.nan
        paper = ""
        if n in (8, 20):
            paper = f"{PAPER_COMPLETION_PCT[('col', n)][0] - PAPER_COMPLETION_PCT[('demo', n)][0]:+.2f}"
        paper_fewer = f"{PAPER_COL_FEWER_SAMPLES_PCT_20:.2f}" if n == 20 else ""
        rows.append(f"| {n} | {gain:+.2f} | {paper} | {fewer:.2f} | {paper_fewer} |")
    if not rows:
        return []
    return ["## CoL against Demo", "",
            "| interactions | completion CoL − Demo (points) | paper | CoL's samples fewer than Demo's (%) | paper |",
            "| ---: | ---: | ---: | ---: | ---: |", *rows, "",
            "Paper, averaged over all interaction counts: +12.81 % completion (s.e. 3.61) with "
            "32.05 % (s.e. 3.25) fewer human samples."]


def plot_bars(cells: Sequence[Cell], path: Path, what: str) -> None:
    """One panel per interaction count, a bar per condition with 1 s.e. error bars (as the
    paper's figures); the paper's values, where it gives them, as black diamonds."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    counts = sorted({c.interactions for c in cells})
    fig, axes = plt.subplots(1, len(counts), figsize=(3.2 * len(counts), 3.4), sharey=True, squeeze=False)
    for ax, n, letter in zip(axes[0], counts, "ABCDEFGHIJ"):
        row = [c for c in cells if c.interactions == n]
        values = [c.completion_pct if what == "completion" else c.samples for c in row]
        ax.bar([LABELS[c.condition] for c in row], [v[0] for v in values],
               yerr=[0.0 if v[1] is None else v[1] for v in values], capsize=4,
               color=[COLOURS[c.condition] for c in row])
        papers = [(i, _paper_value(c, what)) for i, c in enumerate(row)]
        shown = [(i, v) for i, v in papers if v is not None]
        if shown:
            ax.plot([i for i, _ in shown], [v for _, v in shown], "kD", linestyle="none", label="paper")
            ax.legend(loc="lower right", fontsize=8)
        ax.set_title(f"({letter}) {n} interactions")
    axes[0][0].set_ylabel("task completion (%)" if what == "completion" else "human samples")
    if what == "completion":
        axes[0][0].set_ylim(0, 105)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _paper_value(cell: Cell, what: str) -> float | None:
    if what == "completion":
        paper = PAPER_COMPLETION_PCT.get((cell.condition, cell.interactions))
        return None if paper is None else paper[0]
    if cell.interactions == 20 and cell.condition == "col":
        return PAPER_COL_SAMPLES_20[0]
    return None


def write_report(results: Sequence[TrialResult], out_dir: Path) -> Path:
    """``report.md``, ``completion.png`` and ``samples.png`` in ``out_dir``; the report's path."""
    cells = summarise(results)
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / "report.md"
    body = markdown(cells)
    path.write_text("# Experiment: synthetic participants\n\n" + body
                    + "\n![task completion](completion.png)\n\n![human samples](samples.png)\n")
    if cells:
        plot_bars(cells, out_dir / "completion.png", "completion")
        plot_bars(cells, out_dir / "samples.png", "samples")
    return path
