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
import shutil
import sys
import tempfile
import time
from collections.abc import Generator, Iterable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from datetime import UTC, datetime
from pathlib import Path
from typing import TYPE_CHECKING, Literal, Protocol

from tqdm import tqdm

from colcommon.numeric_env import append_record
from companion.config import CompanionConfig
from companion.control.arbiter import Phase
from companion.errors import ColError, ConfigError, SessionOnly
from companion.experiment.grid import (
    START_SEEDS_PER_REPLICATE,
    ExperimentSetup,
    TrainingRun,
    Trial,
    expand,
    plan,
)
from companion.experiment.results import ResultsFile, TrialResult
from companion.experiment.tasks import CONFIG_COPY, RunFn, init_worker, run_training_safely

if TYPE_CHECKING:
    from companion.app import RunResult
    from companion.experiment.batched_eval import BatchedEvaluation
    from companion.msg.episode import EpisodeRecord

log = logging.getLogger(__name__)


def trial_config(setup: ExperimentSetup, trial: Trial | TrainingRun) -> CompanionConfig:
    """The companion's config for a trial or run: budgeted learner seeded by the replicate."""
    start_seed = START_SEEDS_PER_REPLICATE * trial.seed
    cfg = setup.companion
    learner = cfg.learner.model_copy(update={
        "mode": "budgeted", "updates_per_step": setup.exp.updates_per_step, "seed": start_seed})
    session = cfg.session.model_copy(update={"seed": start_seed})
    return cfg.model_copy(update={"learner": learner, "session": session})


def run_trial(setup: ExperimentSetup, trial: Trial, out_dir: Path) -> TrialResult:
    """Train for ``trial.interactions`` episodes, then evaluate the final policy."""
    run = TrainingRun(trial.participant, trial.condition, trial.seed, trial.interactions, (trial.interactions,))
    return run_training(setup, run, out_dir)[0]


def run_training(setup: ExperimentSetup, run: TrainingRun, out_dir: Path) -> list[TrialResult]:
    """Train once, then evaluate the checkpoint of every count in ``run.evaluated_at``.

    The run is in ``out_dir/trials/<run.key>/train``; each trial's evaluation records are in
    ``out_dir/trials/<trial.key>/eval_episodes.jsonl``.
    """
    cfg = trial_config(setup, run)
    run_dir = out_dir / "trials" / run.key / "train"
    for folder in {run_dir, *(out_dir / "trials" / t.key for t in run.trials)}:
        shutil.rmtree(folder, ignore_errors=True)  # a crashed attempt's dataset must not carry over
    run_dir.mkdir(parents=True)
    train = train_run(setup, cfg, run, run_dir)
    results = []
    for trial in run.trials:
        checkpoint = run_dir / "checkpoints" / f"episode_{trial.interactions - 1:03d}.npz"
        trial_dir = out_dir / "trials" / trial.key
        trial_dir.mkdir(parents=True, exist_ok=True)
        t0 = time.monotonic()
        evaluation = evaluate_checkpoint(setup, cfg, checkpoint, trial_dir)
        results.append(trial_result(setup, trial, train.records[:trial.interactions], evaluation,
                               eval_wall_s=time.monotonic() - t0,
                               checkpoint=str(checkpoint.relative_to(out_dir))))
    return results


class Evaluation(Protocol):
    """What a trial's result takes from its evaluation, through the session or batched."""

    @property
    def records(self) -> Sequence[object]: ...

    @property
    def successes(self) -> int: ...


def trial_result(setup: ExperimentSetup, trial: Trial, train: Sequence[EpisodeRecord], evaluation: Evaluation,
            eval_wall_s: float, checkpoint: str) -> TrialResult:
    """A trial's result from its training episodes (a prefix of the run) and its evaluation."""
    intervening = [r for r in train if r.phase == Phase.INTERVENTION.value]
    supervision = "ask" in setup.exp.conditions
    return TrialResult(
        trial=trial, fingerprint=setup.fingerprint(), status="ok",
        eval_runs=len(evaluation.records), eval_successes=evaluation.successes,
        human_samples=sum(r.human_samples for r in train),
        interventions=sum(r.interventions for r in train),
        intervened_steps=sum(r.human_samples for r in intervening),
        missed_takeovers=sum(1 for r in intervening if r.interventions == 0 and not r.success),
        train_successes=sum(1 for r in train if r.success),
        train_wall_s=round(sum(r.wall_time_s for r in train), 2), eval_wall_s=round(eval_wall_s, 2),
        final_checkpoint=checkpoint,
        requests=sum(r.requests for r in train) if supervision else None,
        supervised_steps=sum(r.supervised_steps for r in train) if supervision else None,
        watched_steps=sum(r.supervised_steps for r in intervening) if supervision else None,
        intervention_phase_steps=sum(r.steps for r in intervening) if supervision else None,
    )


def train_run(setup: ExperimentSetup, cfg: CompanionConfig, run: TrainingRun, run_dir: Path) -> RunResult:
    """The participant flies the condition's schedule from a fresh random policy."""
    from companion.app import RunOptions, run_episodes

    train = run_episodes(cfg, RunOptions(
        pilot=f"synthetic:{run.participant}", condition=run.condition, episodes=run.episodes,
        run_dir=run_dir, config_path=setup.config_path, seed=cfg.session.seed, lockstep=True))
    if train.learner_error is not None:
        raise ColError(f"the learner failed in run {run.key}: {train.learner_error}; "
                       f"its run is in {run_dir}; run the grid again to retry the trial")
    return train


def evaluate_checkpoint(setup: ExperimentSetup, cfg: CompanionConfig, checkpoint: Path, trial_dir: Path) -> Evaluation:
    """The final policy alone on the held-out starts; only the episode records are kept.

    With ``eval_inprocess`` the SITL runs in this process (the same episodes, half the CPU:
    :mod:`companion.inprocess`), else in its own process over MAVLink; with
    ``eval_batched`` too, through the batched env's session-free lanes, without the session's
    messages (the same episodes again: :mod:`companion.experiment.batched_eval`), unless the
    config needs the session.
    """
    if setup.exp.eval_inprocess and setup.exp.eval_batched:
        batched = _evaluate_batched(setup, cfg, checkpoint, trial_dir)
        if batched is not None:
            return batched
    return _evaluate_session(setup, cfg, checkpoint, trial_dir)


def _evaluate_batched(setup: ExperimentSetup, cfg: CompanionConfig, checkpoint: Path,
                      trial_dir: Path) -> BatchedEvaluation | None:
    """The batched evaluation and its records; None where only the session flies it (logged)."""
    from companion.experiment.batched_eval import evaluate_batched, why_not_batched, write_records

    reason = why_not_batched(cfg, setup.config_path)
    if reason is not None:
        log.info("evaluation through the session: %s", reason)
        return None
    try:
        evaluation = evaluate_batched(cfg, checkpoint, setup.exp.eval_seed, setup.exp.eval_runs, setup.config_path)
    except SessionOnly as exc:
        log.warning("%s; evaluating through the session instead", exc)
        return None
    write_records(evaluation.records, trial_dir / "eval_episodes.jsonl")
    return evaluation


def _evaluate_session(setup: ExperimentSetup, cfg: CompanionConfig, checkpoint: Path, trial_dir: Path) -> RunResult:
    """The session's evaluation: ``run_episodes`` over MAVLink or in-process."""
    from companion.app import RunOptions, open_vehicle, run_episodes
    from companion.inprocess import inprocess_vehicle

    vehicle = inprocess_vehicle if setup.exp.eval_inprocess else open_vehicle
    with tempfile.TemporaryDirectory(dir=trial_dir) as tmp:  # 100 runs of tlogs and checkpoints: dropped
        evaluation = run_episodes(cfg, RunOptions(
            pilot="none", condition="eval", episodes=setup.exp.eval_runs, checkpoint=checkpoint,
            run_dir=Path(tmp), config_path=setup.config_path, seed=setup.exp.eval_seed,
            learn=False, record=False, lockstep=True), vehicle=vehicle)
        shutil.copy(Path(tmp) / "episodes.jsonl", trial_dir / "eval_episodes.jsonl")
    return evaluation


Backend = Literal["process", "ray"]


def run_grid(setup: ExperimentSetup, out_dir: Path, workers: int, progress: bool = True,
             run_fn: RunFn = run_training, backend: Backend = "process",
             address: str | None = None) -> list[TrialResult]:
    """Run every trial of the grid not yet in ``out_dir/results.jsonl``; all results, grid order.

    ``backend`` "process" runs ``workers`` training runs side by side in local processes;
    "ray" runs them as Ray tasks on the cluster at ``address`` (None: a local instance of
    ``workers`` CPUs; see :mod:`companion.experiment.ray_backend`).
    """
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    if backend not in ("process", "ray"):  # refused before anything is written into out_dir
        raise ConfigError(f"unknown backend {backend!r}; use 'process' or 'ray'")
    if backend == "process" and address is not None:
        raise ConfigError("--address is for --backend ray")
    out_dir = out_dir.resolve()  # Ray workers may run in another working directory
    out_dir.mkdir(parents=True, exist_ok=True)
    results = ResultsFile(out_dir / "results.jsonl")
    fingerprint = setup.fingerprint()
    trials = expand(setup.exp)
    done = results.finished(fingerprint)
    todo = [t for t in trials if t.key not in done]
    _write_setup(setup, out_dir, len(trials), len(done))
    bar = tqdm(total=len(trials), initial=len(trials) - len(todo), unit="trial", desc="experiment",
               disable=not progress)
    batches = _runs(backend, setup, plan(setup.exp, todo), out_dir, workers, run_fn, address)
    try:
        for batch in batches:
            for result in batch:
                results.append(result)
                if result.status == "ok":
                    done[result.trial.key] = result
                bar.update(1)
                bar.set_postfix_str(f"{result.trial.key} {result.status} {result.completion_pct:.0f}%")
    finally:
        # An interrupt that lands here, outside the backend's generator, must still stop it
        # now: left to the garbage collector, the pool went on running every pending run
        # after the command had said "interrupted".
        if isinstance(batches, Generator):
            batches.close()
        bar.close()
    return [done[t.key] for t in trials if t.key in done]


def _runs(backend: Backend, setup: ExperimentSetup, runs: list[TrainingRun], out_dir: Path, workers: int,
          run_fn: RunFn, address: str | None) -> Iterable[list[TrialResult]]:
    if backend == "ray":
        from companion.experiment.ray_backend import run_on_ray

        return run_on_ray(setup, runs, out_dir, workers, run_fn, address)
    if backend != "process":
        raise ConfigError(f"unknown backend {backend!r}; use 'process' or 'ray'")
    if address is not None:
        raise ConfigError("--address is for --backend ray")
    return _run_pool(setup, runs, out_dir, workers, run_fn)


def _run_pool(setup: ExperimentSetup, runs: list[TrainingRun], out_dir: Path, workers: int,
              run_fn: RunFn) -> Iterable[list[TrialResult]]:
    """Each run's results as it finishes, from a pool of fresh (spawned) worker processes."""
    if not runs:
        return
    context = multiprocessing.get_context("spawn")
    pool = ProcessPoolExecutor(max_workers=workers, mp_context=context, initializer=init_worker)
    futures = [pool.submit(run_training_safely, setup, r, out_dir, run_fn) for r in runs]
    try:
        for future in as_completed(futures):
            yield future.result()
    finally:
        for future in futures:  # interrupted: nothing new starts; running runs finish
            future.cancel()
        pool.shutdown(wait=True, cancel_futures=True)


def _write_setup(setup: ExperimentSetup, out_dir: Path, trials: int, done: int) -> None:
    """``experiment.json``: the settings the results belong to, for whoever reads them later."""
    record = {"fingerprint": setup.fingerprint(), "trials": trials, "already_done": done,
              "config_path": None if setup.config_path is None else str(setup.config_path),
              "experiment": setup.exp.model_dump(mode="json"),
              "companion": setup.companion.model_dump(mode="json")}
    (out_dir / "experiment.json").write_text(json.dumps(record, indent=1) + "\n")
    append_record(out_dir, command=sys.argv, started_utc=datetime.now(UTC).isoformat(timespec="seconds"),
                  already_done=done)
    if setup.config_path is not None:  # what `col experiment --verify` reruns trials with
        shutil.copyfile(setup.config_path, out_dir / CONFIG_COPY)
