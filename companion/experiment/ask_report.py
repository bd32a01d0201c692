"""The report's section on asking for help: ``ask`` against ``col``, supervision and completion.

The person's supervision time is the steps they had to watch (``TrialResult.watched_steps``):
every step of CoL's intervention episodes (the person watches the agent throughout), the
request windows of Ask's (from a request until they hand back). Demonstrations are flown by
the person in both and counted apart (``supervised_steps`` holds both). A pair is one
participant and replicate seed at one count, as in the paired completion table.
"""

from __future__ import annotations

import json
import math
import statistics
from collections.abc import Sequence
from pathlib import Path

from companion.experiment.results import TrialResult
from companion.statistics import bootstrap_mean_ci, counted

PairKey = tuple[str, int]
LABELS = {"col": "CoL", "ask": "Ask"}
CONFIDENCE = 0.95
REPORT_SEED = 0
"""As the rest of the report (companion/experiment/report.py), which includes this section."""


def _latest_ok(results: Sequence[TrialResult]) -> list[TrialResult]:
    return counted(results)


def _mean_se(values: Sequence[float]) -> tuple[float, float | None]:
    mean = statistics.fmean(values)
    return mean, (statistics.stdev(values) / math.sqrt(len(values)) if len(values) > 1 else None)


def _cell(results: Sequence[TrialResult], condition: str, n: int) -> dict[PairKey, TrialResult]:
    return {(r.trial.participant, r.trial.seed): r for r in results
            if r.trial.condition == condition and r.trial.interactions == n and r.watched_steps is not None}


def _fmt(values: Sequence[float], digits: int = 1) -> str:
    if not values:
        return ""
    mean, se = _mean_se(values)
    return f"{mean:.{digits}f}" if se is None else f"{mean:.{digits}f} ± {se:.{digits}f}"


def reductions(results: Sequence[TrialResult], n: int, field: str) -> list[float]:
    """Per pair: how much less Ask needed than CoL of ``field`` (watched or supervised steps), in %."""
    ask, col = _cell(results, "ask", n), _cell(results, "col", n)
    out = []
    for key in sorted(ask.keys() & col.keys()):
        base = getattr(col[key], field)
        if base:
            out.append(100.0 * (1.0 - getattr(ask[key], field) / base))
    return out


def _interval(values: Sequence[float]) -> str:
    ci = bootstrap_mean_ci(values, CONFIDENCE, REPORT_SEED)
    return "" if ci is None else f"[{ci[0]:.1f}, {ci[1]:.1f}]"


def _rows(ok: Sequence[TrialResult], n: int) -> list[str]:
    rows = []
    for condition in ("col", "ask"):
        cell = list(_cell(ok, condition, n).values())
        if not cell:
            continue
        watched_pct = [100.0 * r.watched_steps / r.intervention_phase_steps  # type: ignore[operator]
                       for r in cell if r.intervention_phase_steps]
        rows.append(f"| {n} | {LABELS[condition]} | {len(cell)} | {_fmt([r.completion_pct for r in cell], 2)} | "
                    f"{_fmt([float(r.human_samples) for r in cell])} | {_fmt([float(r.requests or 0) for r in cell])} | "
                    f"{_fmt([float(r.watched_steps or 0) for r in cell])} | {_fmt(watched_pct)} | "
                    f"{_fmt([float(r.supervised_steps or 0) for r in cell])} |")
    return rows


def ask_markdown(results: Sequence[TrialResult]) -> list[str]:
    """The supervision table and the paired reductions (empty without ask and col results)."""
    ok = [r for r in _latest_ok(results) if r.watched_steps is not None]
    counts = sorted({r.trial.interactions for r in ok if r.trial.condition == "ask"})
    if not counts:
        return []
    lines = ["## Asking for help: supervision", "",
             "| interactions | condition | trials | completion % | human samples | requests | "
             "watched steps (intervention phase) | watched % of those episodes' steps | "
             "supervised steps (all training) |",
             "| ---: | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for n in counts:
        lines += _rows(ok, n)
    lines += ["", "| interactions | pairs | less watching, Ask vs CoL (%) | 95 % BCa interval | "
              "less supervision incl. demonstrations (%) | 95 % BCa interval |",
              "| ---: | ---: | ---: | ---: | ---: | ---: |"]
    for n in counts:
        watched, total = reductions(ok, n, "watched_steps"), reductions(ok, n, "supervised_steps")
        if watched:
            lines.append(f"| {n} | {len(watched)} | {statistics.fmean(watched):.1f} | {_interval(watched)} | "
                         f"{statistics.fmean(total):.1f} | {_interval(total)} |")
    lines += ["", "Mean ± s.e. over trials. *Watched steps*: the control steps of the intervention-phase "
              "episodes the person had to watch: all of them in CoL, the request windows (request to "
              "hand-back) in Ask. *Supervised steps* add the demonstrations, which the person flies in "
              "both. *Less watching*: per pair (participant, seed), 1 − Ask's ÷ CoL's, then the mean and "
              f"its 95 % BCa bootstrap interval (seed {REPORT_SEED}). The completion difference Ask − CoL "
              "is in the paired table above.", ""]
    return lines


WHO_COLOURS = {"policy": "#66c2a5", "human": "#fc8d62", "hold": "#e7298a", "land": "#555555"}


def plot_ask_trace(trace_path: Path, episode: int | None, out: Path) -> dict[str, object]:
    """A plot of one episode of ``ask_trace.jsonl``: the disagreement against the threshold,
    and who flew (policy, person, holding for an answer); the first intervention-phase
    episode with a request when ``episode`` is None. Returns what it plotted."""
    lines = [json.loads(t) for t in trace_path.read_text().splitlines() if t.strip()]
    if episode is None:
        chosen = next((t for t in lines if t["phase"] == "intervention" and "hold" in t["who"]), None)
    else:
        chosen = next((t for t in lines if t["episode"] == episode), None)
    if chosen is None:
        raise ValueError(f"{trace_path}: no such episode (or no intervention episode with a request)")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    steps = chosen["step"]
    scores = [math.nan if s is None else s for s in chosen["score"]]
    fig, ax = plt.subplots(figsize=(9, 3.6))
    ax.semilogy(steps, scores, color="black", lw=1, label="disagreement (ensemble action variance)")
    if chosen["threshold"] is not None:
        ax.axhline(chosen["threshold"], color="#e7298a", ls="--", lw=1, label="threshold")
    low = min((s for s in scores if s > 0), default=1e-6) / 3
    for who, colour in WHO_COLOURS.items():
        xs = [s for s, w in zip(steps, chosen["who"], strict=True) if w == who]
        if xs:
            ax.scatter(xs, [low] * len(xs), marker="|", s=120, color=colour, label=f"flying: {who}")
    ax.set_xlabel("control step (10.5 Hz)")
    ax.set_ylabel("disagreement")
    run = trace_path.parent.parent.name if trace_path.parent.name == "train" else trace_path.parent.name
    ax.set_title(f"{run}: episode {chosen['episode']} ({chosen['phase']}), asking above the threshold")
    ax.legend(fontsize=7, loc="upper right", ncol=2)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=120)
    plt.close(fig)
    return {"episode": chosen["episode"], "steps": len(steps),
            "who": {w: chosen["who"].count(w) for w in WHO_COLOURS}, "threshold": chosen["threshold"]}


def main(argv: Sequence[str] | None = None) -> None:
    """``python -m companion.experiment.ask_report TRACE [--episode N] --out PNG``"""
    import argparse

    parser = argparse.ArgumentParser(description="plot one episode of an ask_trace.jsonl (score, threshold, who flew)")
    parser.add_argument("trace", type=Path)
    parser.add_argument("--episode", type=int, default=None, help="default: the first intervention episode with a request")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    print(json.dumps(plot_ask_trace(args.trace, args.episode, args.out)))


if __name__ == "__main__":
    main()
