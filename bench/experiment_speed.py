"""Benchmark of the experiment engine: how fast training and evaluation episodes run, how fast
the learner updates, and what that makes of the paper-size grid on 2 cores.

Rates are per core: episodes divided by the CPU seconds of the companion's process and of the
SITL it started (``getrusage`` of self and children), so they do not depend on how busy the
machine is as much as wall times do. Both runs go through the experiment's own functions
(``train_run``, ``evaluate_checkpoint``) with ``configs/paper.toml``'s settings: SITL start,
connect, resets, the lockstep MAVLink loop, camera, detector, policy, stop.

The final policy is evaluated both ways on the same held-out starts: through the in-process
session (``eval_episodes_per_core_s``, ``eval_batched = false``) and through the batched,
session-free evaluation (``eval_batched_episodes_per_core_s``,
``companion/experiment/batched_eval.py``, the experiment's default), in two halves in the order
session, batched, batched, session (a load that changes during the run weighs on both alike);
``eval_batched_same_records`` says whether the two wrote the same episode records (wall times
aside). ``eval_batched_profile``
is a cProfile (on CPU time) of one more batched evaluation: cumulative milliseconds per control
step of its parts and each part's share of the whole (the profiler inflates the milliseconds, and
Python-heavy parts such as the vehicle more than OpenCV calls); its ``parts_without_profiler``
times the SITL's and the detector's parts of another one call by call, the rest being glue.
``eval_batched_lanes``: the batched evaluation's CPU ms per step with 1, 2, 4 and 8 lanes.

``paper_grid_minutes_2_cores`` estimates ``col experiment --config configs/paper.toml
--workers 2`` from the measured rates: its training episodes (prefix evaluation) at the
training rate, its evaluation runs at the in-process session's evaluation rate, split over 2
cores; ``paper_grid_minutes_2_cores_batched_eval`` the same with the batched evaluation's rate.
The evaluation goal is 5 episodes per core-second at ``machine_ref_rt`` 1,186, scaled to this
run's ``machine_ref_rt`` in ``goal_eval_episodes_per_core_s_at_this_machine_ref``.

Last line of stdout: one JSON object. ``--quick`` for a short run.
"""

from __future__ import annotations

import argparse
import cProfile
import dataclasses
import json
import os
import pstats
import resource
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from machine_ref import machine_ref_rt  # noqa: E402

from companion.config import CompanionConfig, LearnerConfig  # noqa: E402
from companion.experiment.batched_eval import evaluate_batched  # noqa: E402
from companion.experiment.grid import ExperimentSetup, TrainingRun, load_experiment, plan  # noqa: E402
from companion.experiment.runner import evaluate_checkpoint, train_run, trial_config  # noqa: E402
from companion.learning.dataset import HumanDataset  # noqa: E402
from companion.learning.learner import Learner  # noqa: E402
from companion.msg.sample import Sample, Source  # noqa: E402

PAPER = REPO / "configs" / "paper.toml"
GOAL_EVAL_EPISODES_PER_CORE_S = 5
GOAL_MACHINE_REF_RT = 1186.0
PROFILED = {  # label: (file, function) whose cumulative time is reported per control step
    "whole evaluation (batched_eval.py run)": ("batched_eval.py", "run"),
    "camera image (camera.py render)": ("camera.py", "render"),
    "pixel noise (disturbance.py add_image_noise)": ("disturbance.py", "add_image_noise"),
    "vehicle: 12 FDM steps + autopilot (vehicle.py step)": ("vehicle.py", "step"),
    "pad detector (perception.py detect)": ("perception.py", "detect"),
    "episode starts (landing_lane.py begin)": ("landing_lane.py", "begin"),
    "telemetry after a frame (direct_sitl.py _fold)": ("direct_sitl.py", "_fold"),
    "policy forward (ensemble.py disagreement)": ("ensemble.py", "disagreement"),
    "setpoints (setpoint_rows.py setpoints)": ("setpoint_rows.py", "setpoints"),
    "setpoint to the vehicle (landing_lane.py velocity)": ("landing_lane.py", "velocity"),
}


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
    (session, session_lines), (batched, batched_lines) = evaluations(evaluation_setup, cfg, checkpoint, work)
    return {
        "train_episodes": len(train.records), "train_wall_s": round(train_wall, 2),
        "train_cpu_s": round(train_cpu, 2),
        "train_episodes_per_core_s": round(len(train.records) / train_cpu, 3),
        **session, **{f"eval_batched_{k.removeprefix('eval_')}": v for k, v in batched.items()},
        "eval_batched_same_records": batched_lines == session_lines,
        "eval_batched_profile": eval_profile(cfg, checkpoint, evaluation_setup, max(10, eval_runs // 2)),
        "eval_batched_lanes": lanes_cpu(cfg, checkpoint, evaluation_setup, max(10, eval_runs // 2)),
    }


def lanes_cpu(cfg: CompanionConfig, checkpoint: Path, setup: ExperimentSetup, runs: int,
              lanes: tuple[int, ...] = (1, 2, 4, 8), rounds: int = 2) -> dict[str, Any]:
    """CPU ms per control step of the batched evaluation of ``runs`` starts with 1, 2, 4 and 8
    lanes side by side (rounds interleaved; the median round): what ``DEFAULT_LANES`` rests on."""
    ms: dict[int, list[float]] = {n: [] for n in lanes}
    for _ in range(rounds):
        for n in lanes:
            result, _, cpu = measured(partial(evaluate_batched, cfg, checkpoint, setup.exp.eval_seed, runs,
                                              setup.config_path, n))
            ms[n].append(1000 * cpu / sum(r.steps for r in result.records))
    return {"episodes": runs, "rounds": rounds,
            "cpu_ms_per_step": {str(n): round(statistics.median(v), 3) for n, v in ms.items()}}


Records = list[dict[str, Any]]


def evaluations(setup: ExperimentSetup, cfg: CompanionConfig, checkpoint: Path,
                work: Path) -> tuple[tuple[dict[str, Any], Records], tuple[dict[str, Any], Records]]:
    """The held-out starts through the in-process session and batched, each path its rates and
    its records without wall times (to compare the two). The starts go in two halves, in the
    order session, batched, batched, session, so a load that changes during the run weighs on
    both paths alike."""
    n = setup.exp.eval_runs
    halves = [(setup.exp.eval_seed, n // 2), (setup.exp.eval_seed + n // 2, n - n // 2)]
    parts: dict[bool, list[tuple[Any, float, float, Records]]] = {False: [], True: []}
    for batched, half in ((False, 0), (True, 0), (True, 1), (False, 1)):
        first, runs = halves[half]
        exp = setup.exp.model_copy(update={"eval_inprocess": True, "eval_batched": batched,
                                           "eval_seed": first, "eval_runs": runs})
        folder = work / f"eval_{'batched' if batched else 'session'}_{half}"
        folder.mkdir()
        result, wall, cpu = measured(partial(evaluate_checkpoint, dataclasses.replace(setup, exp=exp), cfg,
                                             checkpoint, folder))
        lines = [json.loads(line) for line in (folder / "eval_episodes.jsonl").read_text().splitlines()]
        parts[batched].append((result, wall, cpu, [{k: v for k, v in line.items() if k != "wall_time_s"}
                                                   for line in lines]))
    return _rates(parts[False]), _rates(parts[True])


def _rates(parts: list[tuple[Any, float, float, Records]]) -> tuple[dict[str, Any], Records]:
    records = [r for result, _, _, _ in parts for r in result.records]
    steps, cpu, n = sum(r.steps for r in records), sum(p[2] for p in parts), len(records)
    rates = {"eval_episodes": n, "eval_steps_mean": round(steps / n, 1),
             "eval_successes": sum(result.successes for result, _, _, _ in parts),
             "eval_wall_s": round(sum(p[1] for p in parts), 2), "eval_cpu_s": round(cpu, 2),
             "eval_cpu_ms_per_step": round(1000 * cpu / steps, 3), "eval_episodes_per_core_s": round(n / cpu, 3)}
    return rates, [line for p in parts for line in p[3]]


def eval_profile(cfg: CompanionConfig, checkpoint: Path, setup: ExperimentSetup, runs: int) -> dict[str, Any]:
    """Where a batched evaluation's CPU goes: cProfile on CPU time, cumulative ms per control
    step; and, without the profiler (which inflates many small Python calls more than a few
    OpenCV ones), the CPU ms per step of the SITL's and the detector's parts, the rest glue."""
    prof = cProfile.Profile(time.process_time)
    prof.enable()
    result = evaluate_batched(cfg, checkpoint, setup.exp.eval_seed, runs, setup.config_path)
    prof.disable()
    steps = sum(r.steps for r in result.records)
    found: dict[str, float] = {}
    for (file, _, name), row in pstats.Stats(prof).stats.items():  # type: ignore[attr-defined]
        for label, (fname, fn) in PROFILED.items():
            if file.endswith(fname) and name == fn:
                found[label] = round(1000 * row[3] / steps, 3)  # cumulative seconds -> ms per step
    whole = found.get("whole evaluation (batched_eval.py run)", 0.0)
    shares = {k: round(v / whole, 3) for k, v in found.items()} if whole else {}
    return {"episodes": runs, "steps": steps, "cpu_ms_per_step": found, "share_of_step": shares,
            "parts_without_profiler": eval_parts(cfg, checkpoint, setup, runs)}


def eval_parts(cfg: CompanionConfig, checkpoint: Path, setup: ExperimentSetup, runs: int) -> dict[str, Any]:
    """CPU ms per control step of disjoint parts of a batched evaluation (each call timed with
    ``process_time``), and the rest: the evaluation's own glue and the lanes' set-up."""
    from companion.vision.perception import PadDetector
    from sitl.camera import CameraRenderer
    from sitl.disturbance import EpisodeDisturbance
    from sitl.vehicle import SimVehicle

    targets = {"vehicle: 12 FDM steps + autopilot": (SimVehicle, "step"),
               "episode resets: new JSBSim, turbulence pre-roll": (SimVehicle, "reset_episode"),
               "camera image": (CameraRenderer, "render"), "pixel noise": (EpisodeDisturbance, "add_image_noise"),
               "pad detector": (PadDetector, "detect")}
    spent = dict.fromkeys(targets, 0.0)
    saved = [(owner, name, getattr(owner, name)) for owner, name in targets.values()]
    for label, (owner, name) in targets.items():
        setattr(owner, name, _timed(getattr(owner, name), label, spent))
    try:
        c0 = time.process_time()
        result = evaluate_batched(cfg, checkpoint, setup.exp.eval_seed, runs, setup.config_path)
        whole = time.process_time() - c0
    finally:
        for owner, name, original in saved:
            setattr(owner, name, original)
    steps = sum(r.steps for r in result.records)
    ms = {label: round(1000 * s / steps, 3) for label, s in spent.items()}
    ms["rest: evaluation glue, lane set-up"] = round(1000 * (whole - sum(spent.values())) / steps, 3)
    return {"episodes": runs, "whole_cpu_ms_per_step": round(1000 * whole / steps, 3), "cpu_ms_per_step": ms,
            "share_of_step": {k: round(v * steps / 1000 / whole, 3) for k, v in ms.items()}}


def _timed(fn: Callable[..., Any], label: str, spent: dict[str, float]) -> Callable[..., Any]:
    def timed(*args: Any, **kwargs: Any) -> Any:
        t0 = time.process_time()
        try:
            return fn(*args, **kwargs)
        finally:
            spent[label] += time.process_time() - t0

    return timed


def paper_grid_minutes(train_rate: float, eval_rate: float, batched_eval_rate: float, cores: int = 2) -> dict[str, Any]:
    setup = load_experiment(PAPER)
    runs = plan(setup.exp)
    train_eps = sum(r.episodes for r in runs)
    eval_eps = sum(len(r.evaluated_at) for r in runs) * setup.exp.eval_runs

    def minutes(rate: float) -> float:
        return round((train_eps / train_rate + eval_eps / rate) / cores / 60, 1)

    return {"paper_grid_training_episodes": train_eps, "paper_grid_eval_episodes": eval_eps,
            "paper_grid_minutes_2_cores": minutes(eval_rate),
            "paper_grid_minutes_2_cores_batched_eval": minutes(batched_eval_rate)}


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
    grid = paper_grid_minutes(rates["train_episodes_per_core_s"], rates["eval_episodes_per_core_s"],
                              rates["eval_batched_episodes_per_core_s"])
    result = {"bench": "experiment_speed", **rates, "learner_updates_per_s": round(updates),
              **grid, "goal_eval_episodes_per_core_s": GOAL_EVAL_EPISODES_PER_CORE_S,
              "goal_machine_ref_rt": GOAL_MACHINE_REF_RT,
              "goal_eval_episodes_per_core_s_at_this_machine_ref":
                  round(GOAL_EVAL_EPISODES_PER_CORE_S * ref / GOAL_MACHINE_REF_RT, 2),
              "goal_learner_updates_per_s": 4000,
              "goal_paper_grid_minutes_2_cores": 45, "load_avg_1min": round(os.getloadavg()[0], 2),
              "machine_ref_rt": round(ref, 1)}
    print(json.dumps(result))


if __name__ == "__main__":
    main()
