"""Running trials: one trial is a pure function of its setup; a grid runs them in processes.

A trial trains a fresh random policy (seeded by the replicate) over ``interactions`` episodes
of its condition with its synthetic participant, then flies the final checkpoint alone on
the held-out starts ``eval_seed, eval_seed + 1, ...`` (the same for every trial). Each trial
starts its own lockstep SITL on free loopback ports, so trials run side by side in a
:class:`~concurrent.futures.ProcessPoolExecutor`; finished trials go to ``results.jsonl`` as
they complete, and a restarted grid skips them.
"""

from __future__ import annotations

import json
import logging
import multiprocessing
import os
import shutil
import tempfile
import time
from collections.abc import Callable, Iterable
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import TYPE_CHECKING

from tqdm import tqdm

from companion.config import CompanionConfig
from companion.errors import ColError
from companion.experiment.grid import ExperimentSetup, Trial, expand
from companion.experiment.results import ResultsFile, TrialResult

if TYPE_CHECKING:
    from companion.app import RunResult

log = logging.getLogger(__name__)
TrialFn = Callable[[ExperimentSetup, Trial, Path], TrialResult]


def trial_config(setup: ExperimentSetup, trial: Trial) -> CompanionConfig:
    """The companion's config for ``trial``: budgeted learner seeded by the replicate."""
    cfg = setup.companion
    learner = cfg.learner.model_copy(update={
        "mode": "budgeted", "updates_per_step": setup.exp.updates_per_step, "seed": trial.start_seed})
    session = cfg.session.model_copy(update={"seed": trial.start_seed})
    return cfg.model_copy(update={"learner": learner, "session": session})


def run_trial(setup: ExperimentSetup, trial: Trial, out_dir: Path) -> TrialResult:
    """Train, then evaluate the final policy; everything under ``out_dir/trials/<key>``."""
    cfg = trial_config(setup, trial)
    trial_dir = out_dir / "trials" / trial.key
    shutil.rmtree(trial_dir, ignore_errors=True)  # a crashed attempt's dataset must not carry over
    trial_dir.mkdir(parents=True)
    t0 = time.monotonic()
    train = _train(setup, cfg, trial, trial_dir / "train")
    final = trial_dir / "train" / "checkpoints" / f"episode_{trial.interactions - 1:03d}.npz"
    t1 = time.monotonic()
    evaluation = _evaluate(setup, cfg, final, trial_dir)
    return TrialResult(
        trial=trial, fingerprint=setup.fingerprint(), status="ok",
        eval_runs=len(evaluation.records), eval_successes=evaluation.successes,
        human_samples=sum(r.human_samples for r in train.records),
        interventions=sum(r.interventions for r in train.records), train_successes=train.successes,
        train_wall_s=round(t1 - t0, 2), eval_wall_s=round(time.monotonic() - t1, 2),
        final_checkpoint=str(final.relative_to(out_dir)),
    )


def _train(setup: ExperimentSetup, cfg: CompanionConfig, trial: Trial, run_dir: Path) -> RunResult:
    """The participant flies the condition's schedule from a fresh random policy."""
    from companion.app import RunOptions, run_episodes

    train = run_episodes(cfg, RunOptions(
        pilot=f"synthetic:{trial.participant}", condition=trial.condition, episodes=trial.interactions,
        run_dir=run_dir, config_path=setup.config_path, seed=trial.start_seed, lockstep=True))
    if train.learner_error is not None:
        raise ColError(f"the learner failed in trial {trial.key}: {train.learner_error}; "
                       f"its run is in {run_dir}; run the grid again to retry the trial")
    return train


def _evaluate(setup: ExperimentSetup, cfg: CompanionConfig, checkpoint: Path, trial_dir: Path) -> RunResult:
    """The final policy alone on the held-out starts; only the episode records are kept."""
    from companion.app import RunOptions, run_episodes

    with tempfile.TemporaryDirectory(dir=trial_dir) as tmp:  # 100 runs of tlogs and checkpoints: dropped
        evaluation = run_episodes(cfg, RunOptions(
            pilot="none", condition="eval", episodes=setup.exp.eval_runs, checkpoint=checkpoint,
            run_dir=Path(tmp), config_path=setup.config_path, seed=setup.exp.eval_seed,
            learn=False, record=False, lockstep=True))
        shutil.copy(Path(tmp) / "episodes.jsonl", trial_dir / "eval_episodes.jsonl")
    return evaluation


def run_trial_safely(setup: ExperimentSetup, trial: Trial, out_dir: Path,
                     trial_fn: TrialFn = run_trial) -> TrialResult:
    """A failed trial becomes an ``error`` result (run again on resume), not a dead grid."""
    try:
        return trial_fn(setup, trial, out_dir)
    except Exception as exc:  # any failure of one trial is reported, the grid goes on
        log.warning("trial %s failed: %r", trial.key, exc)
        return TrialResult(trial=trial, fingerprint=setup.fingerprint(), status="error", error=repr(exc))


def _init_worker() -> None:
    """One torch thread per worker: the workers share the machine's cores."""
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    import torch

    torch.set_num_threads(1)


def run_grid(setup: ExperimentSetup, out_dir: Path, workers: int, progress: bool = True,
             trial_fn: TrialFn = run_trial) -> list[TrialResult]:
    """Run every trial of the grid not yet in ``out_dir/results.jsonl``; all results, grid order."""
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    out_dir.mkdir(parents=True, exist_ok=True)
    results = ResultsFile(out_dir / "results.jsonl")
    fingerprint = setup.fingerprint()
    trials = expand(setup.exp)
    done = results.finished(fingerprint)
    todo = [t for t in trials if t.key not in done]
    _write_setup(setup, out_dir, len(trials), len(done))
    bar = tqdm(total=len(trials), initial=len(trials) - len(todo), unit="trial", desc="experiment",
               disable=not progress)
    try:
        for result in _run_pool(setup, todo, out_dir, workers, trial_fn):
            results.append(result)
            if result.status == "ok":
                done[result.trial.key] = result
            bar.update(1)
            bar.set_postfix_str(f"{result.trial.key} {result.status} {result.completion_pct:.0f}%")
    finally:
        bar.close()
    return [done[t.key] for t in trials if t.key in done]


def _run_pool(setup: ExperimentSetup, todo: list[Trial], out_dir: Path, workers: int,
              trial_fn: TrialFn) -> Iterable[TrialResult]:
    """Results as trials finish, from a pool of fresh (spawned) worker processes."""
    if not todo:
        return
    context = multiprocessing.get_context("spawn")
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=context, initializer=_init_worker)
    try:
        futures = [pool.submit(run_trial_safely, setup, t, out_dir, trial_fn) for t in todo]
        for future in as_completed(futures):
            yield future.result()
    finally:
        pool.shutdown(wait=True, cancel_futures=True)  # interrupted: finish running trials only


def _write_setup(setup: ExperimentSetup, out_dir: Path, trials: int, done: int) -> None:
    """``experiment.json``: the settings the results belong to, for whoever reads them later."""
    record = {"fingerprint": setup.fingerprint(), "trials": trials, "already_done": done,
              "config_path": None if setup.config_path is None else str(setup.config_path),
              "experiment": setup.exp.model_dump(mode="json"),
              "companion": setup.companion.model_dump(mode="json")}
    (out_dir / "experiment.json").write_text(json.dumps(record, indent=1) + "\n")
