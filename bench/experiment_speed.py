"""Benchmark of the experiment engine: how fast training and evaluation episodes run, how fast
the learner updates, and what that makes of the paper-size grid on 2 cores.

Rates are per core: episodes divided by the CPU seconds of the companion's process and of the
SITL it started (``getrusage`` of self and children), so they do not depend on how busy the
machine is as much as wall times do. Both runs go through the experiment's own functions
(``train_run``, ``evaluate_checkpoint``) with ``configs/paper.toml``'s settings: SITL start,
connect, resets, the lockstep MAVLink loop, camera, detector, policy, stop.

``paper_grid_minutes_2_cores`` estimates ``col experiment --config configs/paper.toml
--workers 2`` from the measured rates: its training episodes (prefix evaluation) at the
training rate, its evaluation runs at the evaluation rate, split over 2 cores.

Last line of stdout: one JSON object. ``--quick`` for a short run.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from machine_ref import machine_ref_rt  # noqa: E402

from companion.config import LearnerConfig  # noqa: E402
from companion.experiment.grid import TrainingRun, load_experiment, plan  # noqa: E402
from companion.experiment.runner import evaluate_checkpoint, train_run, trial_config  # noqa: E402
from companion.learning.dataset import HumanDataset, Sample, Source  # noqa: E402
from companion.learning.learner import Learner  # noqa: E402

PAPER = REPO / "configs" / "paper.toml"


def cpu_s() -> float:
    """CPU seconds of this process and of its finished children (the SITLs it started)."""
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def measured(fn: Callable[[], Any]) -> tuple[Any, float, float]:
    """fn's result, its wall seconds and the CPU seconds it (and its SITL) used."""
    c0, t0 = cpu_s(), time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t0, cpu_s() - c0


def learner_updates_per_s(rounds: int, updates: int) -> float:
    """Learner.step() on a 3,000-sample dataset, one thread; best round (wall clock)."""
    rng = np.random.default_rng(0)
    ds = HumanDataset(None)
    obs = rng.normal(size=(3000, 15)).astype(np.float32)
    ds.extend(Sample(0, i, 0.0, Source.DEMONSTRATION, o, np.tanh(o[:4])) for i, o in enumerate(obs))
    learner = Learner(LearnerConfig(), ds)
    best = 0.0
    for _ in range(rounds):
        t0 = time.perf_counter()
        for _ in range(updates):
            learner.step()
        best = max(best, updates / (time.perf_counter() - t0))
    return best


def episode_rates(work: Path, train_episodes: int, eval_runs: int) -> dict[str, Any]:
    """Train P2 with CoL (half demonstrations, half interventions), then evaluate its policy."""
    setup = load_experiment(PAPER)
    run = TrainingRun("P2", "col", 0, train_episodes, (train_episodes,))
    cfg = trial_config(setup, run)
    train, train_wall, train_cpu = measured(lambda: train_run(setup, cfg, run, work / "train"))
    checkpoint = work / "train" / "checkpoints" / f"episode_{train_episodes - 1:03d}.npz"
    evaluation_setup = setup.__class__(setup.exp.model_copy(update={"eval_runs": eval_runs}), setup.companion,
                                       setup.config_path, setup.sitl_tables)
    (work / "eval").mkdir()
    evaluation, eval_wall, eval_cpu = measured(
        lambda: evaluate_checkpoint(evaluation_setup, cfg, checkpoint, work / "eval"))
    steps = sum(r.steps for r in evaluation.records)
    return {
        "train_episodes": len(train.records), "train_wall_s": round(train_wall, 2),
        "train_cpu_s": round(train_cpu, 2),
        "train_episodes_per_core_s": round(len(train.records) / train_cpu, 3),
        "eval_episodes": len(evaluation.records), "eval_steps_mean": round(steps / len(evaluation.records), 1),
        "eval_successes": evaluation.successes, "eval_wall_s": round(eval_wall, 2),
        "eval_cpu_s": round(eval_cpu, 2),
        "eval_episodes_per_core_s": round(len(evaluation.records) / eval_cpu, 3),
    }


def paper_grid_minutes(train_rate: float, eval_rate: float, cores: int = 2) -> dict[str, Any]:
    setup = load_experiment(PAPER)
    runs = plan(setup.exp)
    train_eps = sum(r.episodes for r in runs)
    eval_eps = sum(len(r.evaluated_at) for r in runs) * setup.exp.eval_runs
    core_s = train_eps / train_rate + eval_eps / eval_rate
    return {"paper_grid_training_episodes": train_eps, "paper_grid_eval_episodes": eval_eps,
            "paper_grid_minutes_2_cores": round(core_s / cores / 60, 1)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="short run (about a minute)")
    args = parser.parse_args()
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    import torch

    torch.set_num_threads(1)
    ref = machine_ref_rt()
    updates = learner_updates_per_s(3 if args.quick else 5, 1000 if args.quick else 3000)
    with tempfile.TemporaryDirectory(prefix="col-bench-") as tmp:
        rates = episode_rates(Path(tmp), 2 if args.quick else 4, 10 if args.quick else 40)
    grid = paper_grid_minutes(rates["train_episodes_per_core_s"], rates["eval_episodes_per_core_s"])
    result = {"bench": "experiment_speed", **rates, "learner_updates_per_s": round(updates),
              **grid, "goal_eval_episodes_per_core_s": 5, "goal_learner_updates_per_s": 4000,
              "goal_paper_grid_minutes_2_cores": 45, "load_avg_1min": round(os.getloadavg()[0], 2),
              "machine_ref_rt": round(ref, 1)}
    print(json.dumps(result))


if __name__ == "__main__":
    main()
