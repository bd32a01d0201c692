"""The grid's results as the paper shows them: a Markdown table beside its numbers, and plots.

Task completion is each final policy's success rate on the held-out starts, in percent;
a cell's mean and standard error (sample standard deviation / sqrt(n)) are over its trials
(participants x replicate seeds), as the paper's error bars are over its four participants.
Human samples are the observation-action pairs recorded in a trial's training.

Beyond the paper's tables: paired comparisons (CoL against Demo and Int, paired by participant
and replicate seed; the statistics are in :mod:`companion.statistics`), task completion per
1,000 human samples, a per-participant table, and learning curves. Everything is computed
from the results alone.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from companion.experiment.results import TrialResult
from companion.statistics import (
    BOOTSTRAP_RESAMPLES,
    EXACT_SIGN_FLIP_MAX_PAIRS,
    MONTE_CARLO_SIGN_FLIPS,
    WILCOXON_ZERO_METHOD,
    PairedComparison,
    compare_paired,
    completion_per_1000_samples,
    counted,
    t_interval,
)

LABELS = {"int": "Int", "demo": "Demo", "col": "CoL", "colplus": "CoL+", "ask": "Ask"}
ORDER = ("int", "demo", "col", "colplus", "ask")  # the paper's bar order, then CoL+ and asking for help
COLOURS = {"int": "#8da0cb", "demo": "#66c2a5", "col": "#fc8d62", "colplus": "#a6d854", "ask": "#e78ac3"}
PAPER_COMPLETION_PCT: dict[tuple[str, int], tuple[float, float]] = {
    ("col", 20): (90.25, 5.63), ("demo", 20): (76.25, 2.72),
    ("col", 8): (74.75, 9.38), ("demo", 8): (54.00, 8.95),
}
"""(condition, interactions) -> (mean, s.e.) reported in the paper's Results."""
PAPER_COL_SAMPLES_20 = (1574.5, 54.22)
PAPER_COL_FEWER_SAMPLES_PCT_20 = 37.79
PAPER_DEMO_SAMPLES_20 = PAPER_COL_SAMPLES_20[0] / (1.0 - PAPER_COL_FEWER_SAMPLES_PCT_20 / 100.0)
"""Not printed in the paper: implied by CoL's 1574.5 samples being 37.79 % fewer."""
PAPER_COL_PER_SAMPLE_RATIO = 1.84
"""The paper's summary over all interaction counts: CoL's task completion per human sample
relative to Demo's (at 20 interactions alone it states 1.90x)."""
COMPARISONS = (("col", "demo"), ("col", "int"), ("colplus", "col"), ("colplus", "demo"), ("ask", "col"))
"""Paired comparisons in the report: a minus b."""
CONFIDENCE = 0.95
REPORT_SEED = 0
"""Seed of the bootstrap and of Monte-Carlo sign flips: the same results give the same report."""


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


def latest_ok(results: Iterable[TrialResult]) -> list[TrialResult]:
    """The trials that count, one per key: :func:`companion.statistics.counted`."""
    return counted(results)


def summarise(results: Iterable[TrialResult]) -> list[Cell]:
    """Cells of the finished trials, by interaction count then the paper's condition order."""
    groups: dict[tuple[str, int], list[TrialResult]] = {}
    for r in latest_ok(results):
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
        paper_fewer = f"{PAPER_COL_FEWER_SAMPLES_PCT_20:.2f}" if n == 20 else ""
        rows.append(f"| {n} | {gain:+.2f} | {_paper_difference('col', 'demo', n)} | {fewer:.2f} | {paper_fewer} |")
    if not rows:
        return []
    return ["## CoL against Demo", "",
            "| interactions | completion CoL − Demo (points) | paper | CoL's samples fewer than Demo's (%) | paper |",
            "| ---: | ---: | ---: | ---: | ---: |", *rows, "",
            "Paper, averaged over all interaction counts: +12.81 % completion (s.e. 3.61) with "
            "32.05 % (s.e. 3.25) fewer human samples."]


def _paper_difference(a: str, b: str, n: int) -> str:
    """The paper's a minus b in completion points at n interactions, where it gives both."""
    pa, pb = PAPER_COMPLETION_PCT.get((a, n)), PAPER_COMPLETION_PCT.get((b, n))
    return "" if pa is None or pb is None else f"{pa[0] - pb[0]:+.2f}"


def _counts(results: Sequence[TrialResult]) -> list[int]:
    return sorted({r.trial.interactions for r in results})


def _conditions(results: Sequence[TrialResult]) -> list[str]:
    present = {r.trial.condition for r in results}
    return [c for c in ORDER if c in present]


# --- paired comparisons -------------------------------------------------------------------

def _fmt_p(p: float, exact: bool = True) -> str:
    text = f"{p:.3f}" if p >= 0.001 else f"{p:.1e}"
    return text if exact else f"≈ {text}"


def _paired_row(c: PairedComparison) -> str:
    ci = "" if c.ci is None else f"[{c.ci[0]:+.2f}, {c.ci[1]:+.2f}]"
    p = "" if c.test is None else _fmt_p(c.test.p, c.test.exact)
    wilcoxon = "" if c.test is None or c.test.p_wilcoxon is None else _fmt_p(c.test.p_wilcoxon)
    better, ties, worse = c.wins_ties_losses
    mean = "" if c.mean is None else f"{c.mean:+.2f}"
    return (f"| {c.interactions} | {LABELS[c.a]} − {LABELS[c.b]} | {c.n} | {mean} | {ci} | {p} | "
            f"{wilcoxon} | {better} / {ties} / {worse} | {_paper_difference(c.a, c.b, c.interactions)} |")


def paired_comparisons(results: Sequence[TrialResult]) -> list[PairedComparison]:
    """CoL against Demo and against Int at every interaction count with at least one pair."""
    found = [compare_paired(results, a, b, n, CONFIDENCE, REPORT_SEED)
             for n in _counts(latest_ok(results)) for a, b in COMPARISONS]
    return [c for c in found if c.n > 0]


PAIRED_NOTE = (
    "A pair is one participant and one replicate seed at one interaction count: both trials "
    "had the same training starts and initial weights, so their difference is free of the "
    "participant's and the seed's share of the variation. A result without its partner, and "
    "failed trials, are left out. *Interval*: 95 % BCa bootstrap interval of the mean paired "
    f"difference (`scipy.stats.bootstrap` on the differences, {BOOTSTRAP_RESAMPLES:,} resamples, "
    f"seed {REPORT_SEED}); none with fewer than two pairs or when every difference is the same. "
    "*p, sign-flip* is the primary p-value: a two-sided paired permutation test of the mean "
    f"difference, exact (all 2^n sign flips) up to {EXACT_SIGN_FLIP_MAX_PAIRS} pairs, else "
    f"Monte-Carlo ({MONTE_CARLO_SIGN_FLIPS:,} flips, seed {REPORT_SEED}, marked ≈). "
    f"*p, Wilcoxon* is the signed-rank test (`zero_method='{WILCOXON_ZERO_METHOD}'`: ties keep "
    "their rank, split between both signs) as a rank-based check. With n pairs the smallest "
    "exact sign-flip p is 2/2^n (0.125 with four pairs): four participants with one seed cannot reach "
    "0.05, run several `seeds`. Bootstrap intervals from a handful of pairs are too narrow; a "
    "participant's pairs share the pilot, so seeds add starts and weights, not participants; "
    "the p-values are not adjusted for the number of comparisons.")


def paired_markdown(results: Sequence[TrialResult]) -> list[str]:
    """The paired table: mean difference, its interval, the tests, and the raw win counts."""
    rows = [_paired_row(c) for c in paired_comparisons(results)]
    if not rows:
        return []
    return ["## Paired comparisons (completion points)", "",
            "| interactions | comparison | pairs | mean difference | 95 % BCa interval | "
            "p, sign-flip (primary) | p, Wilcoxon | first better / tie / worse | paper |",
            "| ---: | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |", *rows, "", PAIRED_NOTE, ""]


# --- completion per human sample ----------------------------------------------------------

PAPER_PER_1000_20 = {"col": 90.25 / PAPER_COL_SAMPLES_20[0] * 1000.0,
                     "demo": 76.25 / PAPER_DEMO_SAMPLES_20 * 1000.0}
"""Completion % per 1,000 samples at 20 interactions from the paper's numbers (Demo implied)."""


def _per_1000(results: Sequence[TrialResult], condition: str, n: int) -> str:
    value = completion_per_1000_samples(results, condition, n)
    return "" if value is None else f"{value:.2f}"


def _ratio(results: Sequence[TrialResult], n: int) -> str:
    col = completion_per_1000_samples(results, "col", n)
    demo = completion_per_1000_samples(results, "demo", n)
    return "" if col is None or not demo else f"{col / demo:.2f}×"


def efficiency_markdown(results: Sequence[TrialResult]) -> list[str]:
    """Completion % per 1,000 human samples per condition and count, and CoL's over Demo's."""
    ok = latest_ok(results)
    conditions = _conditions(ok)
    if not conditions:
        return []
    paper_ratio = PAPER_PER_1000_20["col"] / PAPER_PER_1000_20["demo"]
    rows = []
    for n in _counts(ok):
        ours = " | ".join(_per_1000(ok, c, n) for c in conditions)
        paper = f"{PAPER_PER_1000_20['col']:.2f} / {PAPER_PER_1000_20['demo']:.2f} | {paper_ratio:.2f}×" \
            if n == 20 else " | "
        rows.append(f"| {n} | {ours} | {_ratio(ok, n)} | {paper} |")
    header = " | ".join(LABELS[c] for c in conditions)
    return ["## Task completion per 1,000 human samples", "",
            f"| interactions | {header} | CoL ÷ Demo | paper CoL / Demo | paper CoL ÷ Demo |",
            "| ---: |" + " ---: |" * len(conditions) + " ---: | ---: | ---: |", *rows, "",
            "Mean completion % of a cell divided by its mean human samples, times 1,000: what a "
            "condition gives back for the person's effort. The paper states "
            f"{PAPER_COL_PER_SAMPLE_RATIO:.2f}× (CoL over Demo) averaged over all counts and 1.90× "
            "at 20; its numbers at 20 interactions "
            f"(90.25 % with 1574.5 samples, 76.25 % with ≈ {PAPER_DEMO_SAMPLES_20:.0f}) give "
            f"{paper_ratio:.2f}×.", ""]


# --- per participant ----------------------------------------------------------------------

def _participant_cell(rs: Sequence[TrialResult], row_seeds: int) -> str:
    """Mean completion % and mean samples over a participant's replicates of one cell."""
    if not rs:
        return " | "
    completion = statistics.fmean(r.completion_pct for r in rs)
    samples = statistics.fmean(r.human_samples for r in rs)
    note = "" if len(rs) == row_seeds else f" ({len(rs)} of {row_seeds} seeds)"
    return f"{completion:.2f}{note} | {samples:.0f}"


def participants_markdown(results: Sequence[TrialResult]) -> list[str]:
    """Each participant's completion and samples per condition and count, over replicate seeds."""
    ok = latest_ok(results)
    conditions = _conditions(ok)
    if not conditions:
        return []
    rows = []
    for p in sorted({r.trial.participant for r in ok}):
        for n in _counts(ok):
            mine = [r for r in ok if r.trial.participant == p and r.trial.interactions == n]
            if not mine:
                continue
            seeds = len({r.trial.seed for r in mine})
            cells = [_participant_cell([r for r in mine if r.trial.condition == c], seeds)
                     for c in conditions]
            rows.append(f"| {p} | {n} | {seeds} | " + " | ".join(cells) + " |")
    header = " | ".join(f"{LABELS[c]} completion % | {LABELS[c]} samples" for c in conditions)
    return ["## Per participant, mean over replicate seeds", "",
            f"| participant | interactions | seeds | {header} |",
            "| --- | ---: | ---: |" + " ---: | ---: |" * len(conditions), *rows, ""]


# --- numeric variants ---------------------------------------------------------------------

VARIANTS_DIR = "variants"
"""``<results>/variants/<name>/results.jsonl``: the same trials run again under another numeric
environment (another BLAS kernel, say): each is one more draw of every trial."""
PRIMARY_ENDPOINTS = (("col", "demo", 8), ("col", "demo", 20))
ROBUSTNESS_ENDPOINTS = (*PRIMARY_ENDPOINTS, ("col", "int", 8), ("col", "int", 20))


def read_variants(out_dir: Path) -> dict[str, list[TrialResult]]:
    """The variants kept beside a results folder, by name (none: empty)."""
    from companion.experiment.results import ResultsFile

    root = out_dir / VARIANTS_DIR
    if not root.is_dir():
        return {}
    return {d.name: ResultsFile(d / "results.jsonl").load()
            for d in sorted(root.iterdir()) if (d / "results.jsonl").exists()}


def _endpoint_cell(c: PairedComparison | None) -> str:
    if c is None or c.mean is None:
        return ""
    ci = "" if c.ci is None else f" [{c.ci[0]:+.2f}, {c.ci[1]:+.2f}]"
    return f"{c.mean:+.2f}{ci}"


def _trial_agreement(a: Sequence[TrialResult], b: Sequence[TrialResult]) -> tuple[int, int, float, float]:
    """(trials in both, identical lines, mean and largest |completion difference| in points)."""
    mine = {r.trial.key: r for r in counted(a)}
    theirs = {r.trial.key: r for r in counted(b)}
    keys = sorted(mine.keys() & theirs.keys())
    if not keys:
        return 0, 0, math.nan, math.nan
    same = sum(mine[k].to_json_line() == theirs[k].to_json_line() for k in keys)
    moved = [abs(mine[k].completion_pct - theirs[k].completion_pct) for k in keys]
    return len(keys), same, statistics.fmean(moved), max(moved)


def variants_markdown(primary: Sequence[TrialResult], variants: dict[str, list[TrialResult]],
                      primary_name: str = "primary") -> list[str]:
    """The endpoints under each numeric variant and their spread, and how far single trials moved."""
    if not variants:
        return []
    everyone = {primary_name: counted(primary), **{k: counted(v) for k, v in variants.items()}}
    common = set.intersection(*({r.trial.key for r in rs} for rs in everyone.values()))
    runs = {name: [r for r in rs if r.trial.key in common] for name, rs in everyone.items()}  # the same trials only
    names = list(runs)
    rows = []
    for a, b, n in ROBUSTNESS_ENDPOINTS:
        found = {name: compare_paired(rs, a, b, n, CONFIDENCE, REPORT_SEED) for name, rs in runs.items()}
        means = [c.mean for c in found.values() if c.n > 0 and c.mean is not None]
        if not means:
            continue
        excl = [c.ci is not None and (c.ci[0] > 0 or c.ci[1] < 0) for c in found.values() if c.n > 0]
        cells = " | ".join(_endpoint_cell(found[name] if found[name].n > 0 else None) for name in names)
        primary_mark = " (primary)" if (a, b, n) in PRIMARY_ENDPOINTS else ""
        rows.append(f"| {LABELS[a]} − {LABELS[b]} at {n}{primary_mark} | {cells} | {max(means) - min(means):.2f} | "
                    f"{sum(excl)} of {len(excl)} |")
    agreement = []
    for name in variants:
        both, same, mean_moved, most = _trial_agreement(primary, variants[name])
        agreement.append(f"| {primary_name} vs {name} | {both} | {same} | {mean_moved:.2f} | {most:.2f} |")
    header = " | ".join(names)
    return ["## Numeric variants: the same trials under another numeric environment", "",
            "Each variant ran the trials again with only the numeric environment changed "
            "(its `environment.jsonl` says how). Only trials finished in every run are compared "
            f"({len(common)} here). Mean paired difference in completion points "
            "[95 % BCa interval], as in the paired table.", "",
            f"| endpoint | {header} | spread of the means (points) | intervals excluding 0 |",
            "| --- |" + " ---: |" * len(names) + " ---: | ---: |", *rows, "",
            "| runs | trials in both | identical lines | mean completion change of a trial, absolute (points) | "
            "largest (points) |", "| --- | ---: | ---: | ---: | ---: |", *agreement, "",
            "A trial is closed-loop: a rounding difference grows into another flight, so each "
            "trial is one draw of its cell and only the paired means over replicates carry the "
            "conclusion (docs/experiment.md, \"Reproducible numbers\").", ""]


# --- plots ----------------------------------------------------------------------------------

def _pyplot() -> Any:
    """matplotlib's pyplot on the Agg backend (no display needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_bars(cells: Sequence[Cell], path: Path, what: str) -> None:
    """One panel per interaction count, a bar per condition with 1 s.e. error bars (as the
    paper's figures); the paper's values, where it gives them, as black diamonds."""
    plt = _pyplot()
    counts = sorted({c.interactions for c in cells})
    fig, axes = plt.subplots(1, len(counts), figsize=(3.2 * len(counts), 3.4), sharey=True, squeeze=False)
    for ax, n, letter in zip(axes[0], counts, "ABCDEFGHIJ"):
        row = [c for c in cells if c.interactions == n]
        values = [c.completion_pct if what == "completion" else c.samples for c in row]
        ax.bar([LABELS[c.condition] for c in row], [v[0] for v in values],
               yerr=[0.0 if v[1] is None else v[1] for v in values], capsize=4,
               color=[COLOURS[c.condition] for c in row])
        papers = [(i, _paper_value(c.condition, c.interactions, what)) for i, c in enumerate(row)]
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


def _paper_value(condition: str, interactions: int, what: str) -> float | None:
    if what == "completion":
        paper = PAPER_COMPLETION_PCT.get((condition, interactions))
        return None if paper is None else paper[0]
    return PAPER_COL_SAMPLES_20[0] if interactions == 20 and condition == "col" else None


@dataclass(frozen=True)
class CurvePoint:
    """One condition at one count: the mean over trials and its 95 % t-interval (or None)."""

    interactions: int
    mean: float
    band: tuple[float, float] | None


def curve(results: Sequence[TrialResult], condition: str, what: str) -> list[CurvePoint]:
    """A condition's mean completion % (or human samples) against interactions, with the
    Student-t 95 % interval over its trials: deterministic, and the table's s.e. times t."""
    ok = [r for r in latest_ok(results) if r.trial.condition == condition]
    points = []
    for n in _counts(ok):
        values = [r.completion_pct if what == "completion" else float(r.human_samples)
                  for r in ok if r.trial.interactions == n]
        points.append(CurvePoint(n, statistics.fmean(values), t_interval(values, CONFIDENCE)))
    return points


def _draw_condition(ax: Any, points: Sequence[CurvePoint], condition: str, what: str) -> None:
    colour = COLOURS[condition]
    xs = [p.interactions for p in points]
    ax.plot(xs, [p.mean for p in points], "o-", color=colour, label=LABELS[condition])
    lo = [p.mean if p.band is None else p.band[0] for p in points]
    hi = [p.mean if p.band is None else p.band[1] for p in points]
    if what == "completion":
        lo, hi = [max(0.0, v) for v in lo], [min(100.0, v) for v in hi]
    ax.fill_between(xs, lo, hi, color=colour, alpha=0.2, linewidth=0)
    paper = [(n, v) for n in (4, 8, 12, 20) if (v := _paper_value(condition, n, what)) is not None]
    if paper:
        ax.plot([n for n, _ in paper], [v for _, v in paper], "D", color=colour,
                markeredgecolor="black", linestyle="none", label=f"{LABELS[condition]}, paper")


def plot_curves(results: Sequence[TrialResult], path: Path, what: str) -> None:
    """Completion % (or human samples) against interactions, a line per condition with a 95 %
    t-interval band over trials; the paper's values beside as black-edged diamonds."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6.0, 4.0))
    for condition in _conditions(latest_ok(results)):
        _draw_condition(ax, curve(results, condition, what), condition, what)
    ax.set_xlabel("interactions (training episodes)")
    ax.set_ylabel("task completion (%)" if what == "completion" else "human samples")
    if what == "completion":
        ax.set_ylim(0, 105)
    ax.set_xticks(_counts(latest_ok(results)))
    ax.set_title("mean over trials; shaded: 95 % t-interval; diamonds: paper", fontsize=9)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


FIGURES = ("![learning curve](learning_curve.png)", "![task completion](completion.png)",
           "![human samples against interactions](samples_curve.png)", "![human samples](samples.png)")


def write_report(results: Sequence[TrialResult], out_dir: Path) -> Path:
    """``report.md``, ``completion.png``, ``samples.png``, ``learning_curve.png`` and
    ``samples_curve.png`` in ``out_dir``; the report's path. Variants kept under
    ``out_dir/variants/`` get their section (:func:`variants_markdown`)."""
    cells = summarise(results)
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / "report.md"
    from companion.experiment.ask_report import ask_markdown

    sections = [*paired_markdown(results), *ask_markdown(results), *efficiency_markdown(results),
                *participants_markdown(results), *variants_markdown(results, read_variants(out_dir))]
    body = markdown(cells) + "\n" + "\n".join(sections)
    path.write_text("# Experiment: synthetic participants\n\n" + body + "\n" + "\n\n".join(FIGURES) + "\n")
    if cells:
        plot_bars(cells, out_dir / "completion.png", "completion")
        plot_bars(cells, out_dir / "samples.png", "samples")
        plot_curves(results, out_dir / "learning_curve.png", "completion")
        plot_curves(results, out_dir / "samples_curve.png", "samples")
    return path
