"""What the first intervention episodes teach: the diagnostic the human operator model's
preregistration fixed (docs/experiment.md, "Participants closer to people").

Why Int can match CoL with our participants: if the person takes over early and flies the
expert's own correction from the first episode, Int's first episodes are near-demonstrations.
A person who reacts late, misses trouble and corrects imperfectly teaches less there. Per
training run, over Int's first ``int_episodes`` episodes and CoL's first ``col_episodes``
intervention episodes: the share that failed, the share that failed with no take-over, the
interventions and intervened steps per episode, and the policy's loss on the intervention
samples after each episode. Reads the runs' ``episodes.jsonl`` (a grid's run folder keeps
them under ``trials/<run>/train/``); the committed results hold only the summary.

    python -m companion.experiment.diagnostic runs/human-like > diagnostic.json
"""

from __future__ import annotations

import json
import statistics
import sys
from pathlib import Path
from typing import Any

INTERVENTION = "intervention"


def early_episodes(records: list[dict[str, Any]], condition: str, int_episodes: int = 4,
                   col_episodes: int = 2) -> list[dict[str, Any]]:
    """The run's first intervention-phase episodes the diagnostic looks at."""
    intervening = [r for r in records if r.get("phase") == INTERVENTION]
    return intervening[:int_episodes if condition == "int" else col_episodes]


def summarise_run(records: list[dict[str, Any]], condition: str) -> dict[str, Any] | None:
    early = early_episodes(records, condition)
    if not early:
        return None
    n = len(early)
    failed = [r for r in early if not r.get("success")]
    return {
        "episodes": n,
        "failed_share": len(failed) / n,
        "failed_without_takeover_share": sum(1 for r in failed if r.get("interventions", 0) == 0) / n,
        "interventions_per_episode": sum(r.get("interventions", 0) for r in early) / n,
        "intervened_steps_per_episode": sum(r.get("human_samples", 0) for r in early) / n,
        "loss_intervention": [r.get("loss_intervention") for r in early],
    }


def diagnose(run_root: Path, interactions: int = 20) -> dict[str, Any]:
    """Per condition (Int, CoL at ``interactions``): the runs' figures and their means."""
    out: dict[str, Any] = {}
    for condition in ("int", "col"):
        runs = {}
        for episodes in sorted(run_root.glob(f"trials/*-{condition}-{interactions:02d}-s*/train/episodes.jsonl")):
            records = [json.loads(line) for line in episodes.read_text().splitlines() if line.strip()]
            if len(records) < interactions:
                continue  # a run still going (or stopped): not counted
            summary = summarise_run(records, condition)
            if summary is not None:
                runs[episodes.parent.parent.name] = summary
        out[condition] = {"runs": runs, "mean": _means(list(runs.values()))}
    return out


def _means(runs: list[dict[str, Any]]) -> dict[str, Any] | None:
    if not runs:
        return None
    keys = ("failed_share", "failed_without_takeover_share", "interventions_per_episode", "intervened_steps_per_episode")
    means: dict[str, Any] = {k: round(statistics.fmean(r[k] for r in runs), 3) for k in keys}
    width = max(len(r["loss_intervention"]) for r in runs)
    means["loss_intervention_after_episode"] = [
        _mean_known([r["loss_intervention"][i] for r in runs if i < len(r["loss_intervention"])]) for i in range(width)]
    means["runs"] = len(runs)
    return means


def _mean_known(values: list[float | None]) -> float | None:
    known = [v for v in values if v is not None]
    return round(statistics.fmean(known), 6) if known else None


def main(argv: list[str] | None = None) -> None:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1 or not Path(args[0]).is_dir():
        raise SystemExit("usage: python -m companion.experiment.diagnostic RUN_FOLDER (a grid's --out, with trials/)")
    print(json.dumps(diagnose(Path(args[0])), indent=1))


if __name__ == "__main__":
    main()
