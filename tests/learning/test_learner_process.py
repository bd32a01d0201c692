"""Learner process: the paper's loop in a child process, fed by the CSV, snapshots over a pipe."""

from __future__ import annotations

import os
import signal
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from companion.config import LearnerConfig
from companion.errors import ConfigError, DatasetCorrupt
from companion.learning.dataset import HumanDataset
from companion.learning.learner import Learner, LearnerState
from companion.learning.learner_process import CsvTail, LearnerProcess, LearnerProcessFailed
from companion.learning.runners import make_runner
from companion.msg.sample import Sample, Source
from tests.conftest import wait_until

MAPPING = np.random.default_rng(99).normal(0, 0.4, size=(4, 15)).astype(np.float32)
PERIOD_S = 1 / 10.5


def _target(obs: np.ndarray) -> np.ndarray:
    return np.tanh(obs @ MAPPING.T)


def _grow(ds: HumanDataset, rng: np.random.Generator, n: int) -> None:
    obs = rng.normal(size=(n, 15)).astype(np.float32)
    start = len(ds)
    ds.extend(Sample(0, start + i, 0.0, Source.DEMONSTRATION, o, a)
              for i, (o, a) in enumerate(zip(obs, _target(obs), strict=True)))


def _dataset(tmp_path: Path, rng: np.random.Generator, n: int) -> HumanDataset:
    ds = HumanDataset(tmp_path / "human.csv")
    _grow(ds, rng, n)
    return ds


def _wait_for(predicate: Callable[[], bool], timeout_s: float = 30.0) -> bool:
    """Generous: starting a child (an interpreter plus torch) is slow on a loaded machine."""
    return wait_until(predicate, timeout_s)


def _gone(pid: int) -> bool:
    """No process (not even a zombie) with this id."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    return False


def test_tail_reads_complete_lines_only(tmp_path: Path, rng: np.random.Generator) -> None:
    ds = _dataset(tmp_path, rng, 5)
    tail = CsvTail(ds.path)  # type: ignore[arg-type]
    assert len(tail) == 5
    np.testing.assert_array_equal(tail.view().obs, ds.view().obs)
    line = (tmp_path / "human.csv").read_bytes().splitlines(keepends=True)[-1]
    with open(tmp_path / "human.csv", "ab") as f:
        f.write(line[:20])  # a torn line: a write in progress
        f.flush()
        assert tail.poll() == 5
        f.write(line[20:] + b"0,1,2\n")
    with pytest.raises(DatasetCorrupt, match="line 8 has 3 columns"):
        tail.poll()
    tail.close()


def test_learns_a_mapping_follows_new_samples_and_stops_cleanly(
        tmp_path: Path, rng: np.random.Generator) -> None:
    ds = _dataset(tmp_path, rng, 400)
    learner = Learner(LearnerConfig(learning_rate=1e-3, thread_nice=0), ds)  # not about priority
    runner = make_runner(Learner(LearnerConfig(mode="process"), ds))
    assert isinstance(runner, LearnerProcess)
    with LearnerProcess(learner) as proc:
        assert _wait_for(lambda: proc.state is LearnerState.IDLE
                         and proc.latest_snapshot.dataset_size_trained == 400)
        test_obs = rng.normal(size=(300, 15)).astype(np.float32)

        def held_out_mse() -> float:
            return float(np.mean((proc.latest_snapshot.act(test_obs) - _target(test_obs)) ** 2))

        assert _wait_for(lambda: held_out_mse() < 0.03, 5.0), held_out_mse()  # round's last one
        snap = proc.latest_snapshot
        assert learner.latest_snapshot is snap  # the checkpoints see the child's training
        ticks = []
        for _ in range(10):  # one new sample per 10.5 Hz tick
            _grow(ds, rng, 1)
            n, start = len(ds), time.monotonic()
            while proc.on_control_step().dataset_size_trained < n and time.monotonic() - start < 1:
                time.sleep(PERIOD_S)
            ticks.append(round((time.monotonic() - start) / PERIOD_S))
        assert np.median(ticks) <= 1 and max(ticks) <= 3, ticks
        pid = proc.pid
    assert proc.state is LearnerState.STOPPED and proc.error is None
    final = learner.latest_snapshot
    assert final.dataset_size_trained == 410 and final.version >= 10
    assert pid is not None and _gone(pid)


def test_a_killed_child_is_noticed(tmp_path: Path, rng: np.random.Generator) -> None:
    ds = _dataset(tmp_path, rng, 100)
    proc = LearnerProcess(Learner(LearnerConfig(loss_threshold=1e-12), ds))
    try:
        proc.start()
        assert _wait_for(lambda: proc.latest_snapshot.version > 0)
        assert proc.pid is not None
        os.kill(proc.pid, signal.SIGKILL)
        assert _wait_for(lambda: proc.error is not None)
        assert "exit code" in str(proc.error) and proc.state is LearnerState.FAILED
        assert proc.latest_snapshot.version > 0
    finally:
        proc.stop(timeout_s=2.0)
    assert _gone(proc.pid)


def test_process_mode_needs_a_dataset_file() -> None:
    with pytest.raises(ConfigError, match='mode = "thread"'):
        make_runner(Learner(LearnerConfig(mode="process"), HumanDataset(None)))


def _control_loop(ds: HumanDataset, rng: np.random.Generator, snapshot_of, ticks: int,  # type: ignore[no-untyped-def]
                  until=lambda: True, max_ticks: int = 2000) -> np.ndarray:
    """A 10.5 Hz loop that flies snapshots and records a sample per tick, for ``ticks`` ticks and
    then on until ``until()`` holds (or ``max_ticks``): period jitter (ms)."""
    stamps: list[float] = []
    next_t = time.perf_counter()
    while len(stamps) < ticks or (not until() and len(stamps) < max_ticks):
        next_t += PERIOD_S
        time.sleep(max(0.0, next_t - time.perf_counter()))
        stamps.append(time.perf_counter())
        snapshot_of().act(np.zeros(15, np.float32))
        _grow(ds, rng, 1)
    return np.abs(np.diff(stamps) - PERIOD_S) * 1e3


def test_control_keeps_ticking_beside_a_busy_child_and_its_failure_reported(
        tmp_path: Path, rng: np.random.Generator) -> None:
    ds = _dataset(tmp_path, rng, 300)
    learner = Learner(LearnerConfig(loss_threshold=1e-12, max_updates=10**6), ds)
    with LearnerProcess(learner) as proc:  # the jitter itself is a bench figure (bench/learner.py)
        assert _wait_for(lambda: proc.state is LearnerState.TRAINING)
        v0 = proc.latest_snapshot.version
        busy_ms = _control_loop(ds, rng, proc.on_control_step, 25,
                                until=lambda: proc.latest_snapshot.version - v0 > 300)
        busy_updates = proc.latest_snapshot.version - v0
        assert len(busy_ms) >= 24 and np.all(np.isfinite(busy_ms))
        # 300 updates beside the loop, however many ticks a loaded machine needed for them
        assert busy_updates > 300, f"the child did only {busy_updates} updates in {len(busy_ms) + 1} ticks: not busy"
        # then a failure in the child (an unreadable row): reported, last good snapshot kept
        with open(tmp_path / "human.csv", "ab") as f:
            f.write(b"not,a,row\n")
        assert _wait_for(lambda: proc.error is not None)
        good = proc.latest_snapshot
        assert proc.state is LearnerState.FAILED and isinstance(proc.error, LearnerProcessFailed)
        assert "DatasetCorrupt" in str(proc.error) and "Traceback" in str(proc.error)
        assert np.all(np.isfinite(proc.on_control_step().act(np.zeros(15))))
        pid = proc.pid
    assert proc.latest_snapshot is good and proc.state is LearnerState.FAILED
    assert pid is not None and _gone(pid)
