"""Benchmark of the learner: update rate, sample-to-policy latency, control-loop jitter.

Live mode as in flight: a ``LearnerThread`` (``--runner thread``) or a ``LearnerProcess``
(``--runner process``; default: the config's ``mode``) trains while this process simulates the
control loop at 10.5 Hz. Every tick the loop reads the latest snapshot, flies it (``act``) and
records one of the person's samples to a real CSV file. A sample's latency ends at the first
tick whose snapshot was trained on a dataset that held it (``dataset_size_trained``), so it is
at least one control period (95 ms); ``sample_to_publish_ms_*`` is the learner's own share
(sample recorded -> snapshot published). The live run sets the loss threshold out of reach, so
the learner trains without pause the whole time: the worst case for both jitter and latency.
The same loop without a learner runs half the time before and half after (``..._idle``): the
machine's own timing noise under whatever else is running on it. ``--busy-procs N`` starts N
CPU-bound processes for the whole run, to measure on a loaded machine on purpose.

Last line of stdout: one JSON object. Run with ``--quick`` for a short run.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from load import busy_processes  # noqa: E402
from machine_ref import machine_ref_rt  # noqa: E402

from companion.config import LearnerConfig  # noqa: E402
from companion.learning.dataset import HumanDataset
from companion.learning.learner import Learner  # noqa: E402
from companion.learning.learner_process import LearnerProcess  # noqa: E402
from companion.learning.policy import PolicySnapshot  # noqa: E402
from companion.learning.runners import LearnerThread  # noqa: E402
from companion.msg.sample import Sample, Source

RATE_HZ = 10.5


class _Expert:
    """A noisy linear-tanh 'person': learnable, but never below the loss threshold."""

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng
        self.gain = rng.normal(0, 0.4, size=(4, 15)).astype(np.float32)

    def sample(self, episode: int, step: int) -> Sample:
        obs = self.rng.normal(size=15).astype(np.float32)
        action = np.clip(np.tanh(self.gain @ obs) + self.rng.normal(0, 0.1, 4), -1, 1)
        return Sample(episode, step, step / RATE_HZ, Source.DEMONSTRATION, obs, action)


def measure_updates_per_s(config: LearnerConfig, n_updates: int, rng: np.random.Generator) -> float:
    """Plain ``step()`` rate (minibatch 64) on a 2000-sample dataset, one torch thread."""
    expert = _Expert(rng)
    dataset = HumanDataset(None)
    dataset.extend(expert.sample(0, i) for i in range(2000))
    learner = Learner(config, dataset)
    for _ in range(50):
        learner.step()
    t0 = time.perf_counter()
    for _ in range(n_updates):
        learner.step()
    return n_updates / (time.perf_counter() - t0)


def control_loop(duration_s: float, on_tick) -> np.ndarray:
    """Run ``on_tick(t)`` at RATE_HZ on absolute deadlines; returns the tick times."""
    period_s = 1.0 / RATE_HZ
    stamps = []
    next_t = time.perf_counter() + period_s
    end_t = next_t + duration_s
    while next_t < end_t:
        time.sleep(max(0.0, next_t - time.perf_counter()))
        now = time.perf_counter()
        stamps.append(now)
        on_tick(now)
        next_t += period_s
    return np.array(stamps)


def jitter_ms(stamps: np.ndarray) -> np.ndarray:
    return np.abs(np.diff(stamps) - 1.0 / RATE_HZ) * 1e3


class _LiveRun:
    """The control tick of the live run plus the bookkeeping of latencies."""

    def __init__(self, dataset: HumanDataset, runner: LearnerThread | LearnerProcess,
                 expert: _Expert) -> None:
        self.dataset, self.runner, self.expert = dataset, runner, expert
        self.recorded_at: list[float] = []  # index i -> time sample i was recorded
        self.flown_at: dict[int, float] = {}
        self.child_publishes: list[tuple[float, int]] = []  # process runner: (time, size)
        self.obs = np.zeros(15, np.float32)

    def tick(self, now: float) -> None:
        snap = self.runner.on_control_step()
        if isinstance(self.runner, LearnerProcess) and snap.dataset_size_trained > (
                self.child_publishes[-1][1] if self.child_publishes else 0):
            self.child_publishes.append((self.runner.size_published_at_s, snap.dataset_size_trained))
        for i in range(len(self.flown_at), min(snap.dataset_size_trained, len(self.recorded_at))):
            self.flown_at[i] = now
        snap.act(self.obs)
        self.dataset.append(self.expert.sample(0, len(self.recorded_at)))
        self.recorded_at.append(time.perf_counter())


def _record_publishes(learner: Learner) -> list[tuple[float, int]]:
    """Wrap ``publish`` to note when each snapshot (and for which dataset size) appeared."""
    log: list[tuple[float, int]] = []
    publish = learner.publish

    def timed_publish() -> PolicySnapshot:
        snap = publish()
        log.append((time.perf_counter(), snap.dataset_size_trained))
        return snap

    learner.publish = timed_publish  # type: ignore[method-assign]
    return log


def _publish_latencies_ms(recorded_at: list[float], publishes: list[tuple[float, int]]) -> np.ndarray:
    out, j = [], 0
    for i, t_rec in enumerate(recorded_at):
        while j < len(publishes) and publishes[j][1] < i + 1:
            j += 1
        if j < len(publishes):
            out.append((publishes[j][0] - t_rec) * 1e3)
    return np.array(out)


def _start_runner(kind: str, learner: Learner) -> LearnerThread | LearnerProcess:
    """Start the runner and wait until it trains (a process needs a few seconds to start)."""
    runner = LearnerProcess(learner) if kind == "process" else LearnerThread(learner)
    runner.start()
    deadline = time.monotonic() + 120.0
    while runner.latest_snapshot.version == 0 and time.monotonic() < deadline:
        time.sleep(0.05)
    return runner


def live_run(config: LearnerConfig, duration_s: float, rng: np.random.Generator, kind: str) -> dict:
    """Fly ``duration_s`` at 10.5 Hz while the ``kind`` runner trains flat out."""
    with tempfile.TemporaryDirectory() as tmp:
        dataset = HumanDataset(Path(tmp) / "human.csv")
        learner = Learner(config, dataset)
        publishes = _record_publishes(learner)
        expert = _Expert(rng)
        dataset.extend(expert.sample(0, i) for i in range(1))  # something to train on at once
        runner = _start_runner(kind, learner)
        run = _LiveRun(dataset, runner, expert)
        run.recorded_at.append(float("-inf"))  # the seed sample is not measured
        try:
            updates0 = runner.latest_snapshot.version
            stamps = control_loop(duration_s, run.tick)
            updates = runner.latest_snapshot.version - updates0
        finally:
            runner.stop()
        dataset.close()
    if kind == "process":
        publishes = run.child_publishes
    flown = np.array([(run.flown_at[i] - run.recorded_at[i]) * 1e3 for i in sorted(run.flown_at)
                      if i > 0])
    to_publish = _publish_latencies_ms(run.recorded_at, publishes)
    to_publish = to_publish[np.isfinite(to_publish)]
    jit = jitter_ms(stamps)
    return {
        "sample_to_policy_ms_p50": round(float(np.percentile(flown, 50)), 2),
        "sample_to_policy_ms_p95": round(float(np.percentile(flown, 95)), 2),
        "sample_to_publish_ms_p50": round(float(np.percentile(to_publish, 50)), 3),
        "sample_to_publish_ms_p95": round(float(np.percentile(to_publish, 95)), 3),
        "control_period_jitter_ms_p50": round(float(np.percentile(jit, 50)), 3),
        "control_period_jitter_ms_p90": round(float(np.percentile(jit, 90)), 3),
        "control_period_jitter_ms_p99": round(float(np.percentile(jit, 99)), 3),
        "control_period_jitter_ms_max": round(float(jit.max()), 3),
        "live_updates_per_s": round(updates / duration_s, 1),
        "ticks": int(len(stamps)),
        "samples_flown": int(len(flown)),
        "learner_state_at_end": runner.state.value,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="short run (about 20 s)")
    parser.add_argument("--control-guard-s", type=float, default=None,
                        help="override control_guard_s (0 turns the tick guard off, to compare)")
    parser.add_argument("--runner", choices=("thread", "process"), default=None,
                        help="learner runner (default: the config's mode; thread if budgeted)")
    parser.add_argument("--busy-procs", type=int, default=0,
                        help="start this many CPU-bound processes for the run (a loaded machine)")
    parser.add_argument("--duration-s", type=float, default=None, help="live run length")
    args = parser.parse_args()
    duration_s = args.duration_s or (8.0 if args.quick else 60.0)
    config = LearnerConfig()
    kind = args.runner or (config.mode if config.mode in ("thread", "process") else "thread")
    machine_ref = machine_ref_rt()  # at the start, before the bench's own work (and --busy-procs)
    with busy_processes(args.busy_procs):
        run_all(args, config, kind, duration_s, machine_ref)


def run_all(args: argparse.Namespace, config: LearnerConfig, kind: str, duration_s: float,
            machine_ref: float) -> None:
    """Update rate, idle loop, live run, idle loop; prints the JSON line."""
    if args.control_guard_s is not None:
        config = config.model_copy(update={"control_guard_s": args.control_guard_s})
    torch.set_num_threads(config.torch_threads)
    rng = np.random.default_rng(0)

    updates_per_s = measure_updates_per_s(config, 500 if args.quick else 3000, rng)
    busy = config.model_copy(update={"loss_threshold": 1e-9})
    idle_before = jitter_ms(control_loop(duration_s / 2, lambda now: None))
    live = live_run(busy, duration_s, rng, kind)
    idle = np.concatenate([idle_before, jitter_ms(control_loop(duration_s / 2, lambda now: None))])
    print(f"updates/s {updates_per_s:.0f}; sample->policy p50 {live['sample_to_policy_ms_p50']} ms "
          f"p95 {live['sample_to_policy_ms_p95']} ms (learner's share p95 "
          f"{live['sample_to_publish_ms_p95']} ms); jitter p99 "
          f"{live['control_period_jitter_ms_p99']} ms busy, {np.percentile(idle, 99):.3f} ms idle")
    result = {
        "updates_per_s": round(updates_per_s, 1),
        "runner": kind,
        "busy_procs": args.busy_procs,
        **live,
        "control_period_jitter_ms_p50_idle": round(float(np.percentile(idle, 50)), 3),
        "control_period_jitter_ms_p90_idle": round(float(np.percentile(idle, 90)), 3),
        "control_period_jitter_ms_p99_idle": round(float(np.percentile(idle, 99)), 3),
        "control_rate_hz": RATE_HZ,
        "duration_s": duration_s,
        "torch_threads": config.torch_threads,
        "publish_every_updates": config.publish_every_updates,
        "control_guard_s": config.control_guard_s,
        "learner_always_busy": True,
        "cpu_count": os.cpu_count(),
        "loadavg_1min": round(os.getloadavg()[0], 2),
        "note": "shared machine: other engineers' jobs run concurrently",
        "machine_ref_rt": round(machine_ref, 1),
    }
    print(json.dumps(result))


if __name__ == "__main__":
    main()
