"""What every backend runs for one training run, in a local worker process or a Ray task.

Kept apart from the runner so that the Ray backend, which the runner starts, needs nothing
from the runner itself.
"""

from __future__ import annotations

import logging
import os
import traceback
from collections.abc import Callable
from pathlib import Path

from companion.experiment.grid import ExperimentSetup, TrainingRun
from companion.experiment.results import TrialResult

log = logging.getLogger(__name__)
RunFn = Callable[[ExperimentSetup, TrainingRun, Path], list[TrialResult]]
"""Trains one run and returns its trials' results (``runner.run_training``, or a test's fake)."""
CONFIG_COPY = "config.toml"
"""The experiment file, copied into the results folder so that its trials can be rerun (and
read by workers that run in another directory or on another machine)."""


def run_training_safely(setup: ExperimentSetup, run: TrainingRun, out_dir: Path,
                        run_fn: RunFn) -> list[TrialResult]:
    """A failed run gives ``error`` results for its trials (run again on resume), not a dead grid."""
    try:
        return run_fn(setup, run, out_dir)
    except Exception as exc:  # any failure of one run is reported, the grid goes on
        log.warning("training run %s failed: %r", run.key, exc, exc_info=True)
        error = f"{type(exc).__name__}: {exc} (at {_where(exc)})"  # str() keeps an OSError's file name
        return [TrialResult(trial=t, fingerprint=setup.fingerprint(), status="error", error=error)
                for t in run.trials]


def _where(exc: BaseException) -> str:
    """Where it was raised and the innermost frame of the project's own code on the way, e.g.
    ``shutil.py:256 in copyfile, from runner.py:133 in evaluate_checkpoint``."""
    frames = traceback.extract_tb(exc.__traceback__)
    if not frames:
        return "unknown place"
    ours = [f for f in frames if "/companion/" in f.filename or "/sitl/" in f.filename]
    places = [frames[-1]] + ([ours[-1]] if ours and ours[-1] is not frames[-1] else [])
    return ", from ".join(f"{Path(f.filename).name}:{f.lineno} in {f.name}" for f in places)


def init_worker() -> None:
    """One thread per library in a worker: the workers share the machine's cores."""
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    import cv2
    import torch

    torch.set_num_threads(1)
    cv2.setNumThreads(1)  # OpenCV's own pool spins on the other core for a gain lockstep cannot use
