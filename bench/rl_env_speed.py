"""How many landing-env steps per second: the MAVLink env, the in-process env, and the
in-process env in 2 worker processes (stable-baselines3 ``SubprocVecEnv``), 2 side by side with
no hand-over (what two busy cores cost each other), and 8 envs grouped in 2 workers (the hand-over
paid once per 4 env steps, ``GroupedSubprocVecEnv``); where one in-process step's time
goes (a cProfile of the same stepping); and the floor: the CPU time of the work every step of
this task needs whatever the env (vehicle, camera image, pad detection), the rest being glue.
Then the batched, session-free env (``companion/rl/batched_env.py``, the same episodes): 8 envs
in this process, 8 in 2 worker processes of 4 (one message per batch and step), 2 batches of 4
side by side in their own processes with no pipe (what two of our busy processes cost each
other, without the hand-over), where its step's CPU time goes (the same work, and what is left
of the glue), and the in-process env and a batch stepped in turns (``interleaved``: on a machine
whose load changes during the run, their ratio is the figure that compares them).

Random actions in the 2-action task on the calibrated task (``configs/paper.toml``), episodes
reset as they end, as PPO steps an env. Goal: 2,000 env steps/s in total on a 2-core machine.

Each measurement gives wall-clock steps per second (what this machine, as loaded now, did) and
CPU milliseconds per step (the processes' own CPU time: the SITL side included, since it runs
in the same process; for the workers, their CPU time read from /proc), from which
``*_steps_per_s_per_idle_core`` = 1000 / CPU ms per step: what one core to itself would give.
On a shared machine the wall-clock figures fall with the load; the CPU figures do not.

The wall-clock figures are measured over the whole stepping, all processes together; the CPU
figures add up the CPU seconds of every process taking part (ours and the workers').

    python bench/rl_env_speed.py [--quick] [--steps N] [--parts NAME,...]
"""

from __future__ import annotations

import argparse
import cProfile
import json
import os
import pstats
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
from machine_ref import machine_ref_rt  # noqa: E402

from companion.config import load_companion_config  # noqa: E402
from companion.rl.gym_env import LandingEnv  # noqa: E402
from companion.rl.vec_env import make_vec_env  # noqa: E402

PAPER = REPO / "configs" / "paper.toml"
GOAL_STEPS_PER_S = 2000
GOAL_MACHINE_REF_RT = 1186.0  # the machine reference the goal was set at: it scales with machine_ref_rt


def _cpu_s(pids: list[int]) -> float:
    """CPU seconds (user + system) used so far by these processes (Linux /proc)."""
    tick = os.sysconf("SC_CLK_TCK")
    total = 0.0
    for pid in pids:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        total += (int(fields[11]) + int(fields[12])) / tick
    return total


def _rates(steps: int, wall_s: float, cpu_s: float) -> dict[str, float]:
    return {"steps_per_s": round(steps / wall_s, 1), "cpu_ms_per_step": round(1000 * cpu_s / steps, 3),
            "steps_per_s_per_idle_core": round(steps / cpu_s, 1)}


def _step_env(env: LandingEnv, steps: int, rng: np.random.Generator) -> dict[str, float]:
    """One env over ``steps`` steps (resetting as episodes end): wall and CPU rates."""
    env.reset(seed=0)
    t0, c0 = time.perf_counter(), time.process_time()
    for _ in range(steps):
        _, _, terminated, truncated, _ = env.step(rng.uniform(-1, 1, 2).astype(np.float32))
        if terminated or truncated:
            env.reset()
    return _rates(steps, time.perf_counter() - t0, time.process_time() - c0)


def single(inprocess: bool, steps: int) -> dict[str, float]:
    """One env; over MAVLink the SITL process's CPU time counts too."""
    cfg = load_companion_config(PAPER)
    env = LandingEnv(2, cfg, config_path=PAPER, inprocess=inprocess)
    try:
        if inprocess:
            return _step_env(env, steps, np.random.default_rng(0))
        sitl_pids = [int(p) for p in Path(f"/proc/{os.getpid()}/task/{os.getpid()}/children").read_text().split()]
        before = _cpu_s(sitl_pids)
        rates = _step_env(env, steps, np.random.default_rng(0))
        sitl_ms = 1000 * (_cpu_s(sitl_pids) - before) / steps
        cpu_ms = rates["cpu_ms_per_step"] + sitl_ms
        return {**rates, "cpu_ms_per_step": round(cpu_ms, 3), "steps_per_s_per_idle_core": round(1000 / cpu_ms, 1)}
    finally:
        env.close()


def vectorised(n_envs: int, steps: int, workers: int | None = None) -> dict[str, float]:
    """``n_envs`` in-process envs in worker processes, one per env or ``workers`` stepping a group
    each: total rates (workers' and our CPU time)."""
    venv = make_vec_env(2, load_companion_config(PAPER), n_envs, PAPER, workers=workers)
    rng = np.random.default_rng(0)
    try:
        venv.seed(0)
        venv.reset()
        pids = [p.pid for p in venv.processes]  # type: ignore[attr-defined]
        cores = len(pids)
        rounds = max(1, steps // n_envs)
        t0, c0, w0 = time.perf_counter(), time.process_time(), _cpu_s(pids)
        for _ in range(rounds):
            venv.step(rng.uniform(-1, 1, (n_envs, 2)).astype(np.float32))  # auto-resets
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0 + _cpu_s(pids) - w0
        rates = _rates(rounds * n_envs, wall, cpu)
        return {**rates, "processes": cores,
                f"steps_per_s_on_{cores}_idle_cores": round(cores * 1000 / rates["cpu_ms_per_step"], 1)}
    finally:
        venv.close()


def _single_worker(steps: int, seed: int, queue: Any) -> None:
    """A child process: one in-process env stepped on its own; its rates go back on ``queue``."""
    os.environ["OMP_NUM_THREADS"] = "1"
    cfg = load_companion_config(PAPER)
    env = LandingEnv(2, cfg, config_path=PAPER, inprocess=True)
    try:
        queue.put(_step_env(env, steps, np.random.default_rng(seed)))
    finally:
        env.close()


def side_by_side(n_envs: int, steps: int) -> dict[str, float]:
    """``n_envs`` in-process envs, each stepped by a process of its own with no hand-over at all:
    the CPU ms per step they need when the cores are all busy. Beside ``single(True)`` (one core
    busy) and ``vectorised`` (the same envs behind pipes) it splits the workers' extra cost into
    the hand-over and what busy neighbours cost (shared cache, memory bandwidth, clock)."""
    import multiprocessing as mp

    ctx = mp.get_context("forkserver")
    queue = ctx.Queue()
    procs = [ctx.Process(target=_single_worker, args=(steps, seed, queue)) for seed in range(n_envs)]
    t0 = time.perf_counter()
    for proc in procs:
        proc.start()
    rates = [queue.get(timeout=600) for _ in procs]
    for proc in procs:
        proc.join()
    wall = time.perf_counter() - t0  # includes each child's start (SITL and imports): a lower bound
    cpu_ms = sum(r["cpu_ms_per_step"] for r in rates) / n_envs
    return {"cpu_ms_per_step": round(cpu_ms, 3), "steps_per_s_per_idle_core": round(1000 / cpu_ms, 1),
            "steps_per_s_each": [r["steps_per_s"] for r in rates],
            "steps_per_s_incl_start": round(n_envs * steps / wall, 1),
            f"steps_per_s_on_{n_envs}_idle_cores": round(n_envs * 1000 / cpu_ms, 1)}


def profile(steps: int) -> dict[str, Any]:
    """Where an in-process step's CPU time goes: cProfile (on CPU time, so other processes do not
    count) cumulative milliseconds per env step of the main parts, and each part's share of the
    whole step (the profiler's own overhead inflates the milliseconds, less the shares)."""
    cfg = load_companion_config(PAPER)
    env = LandingEnv(2, cfg, config_path=PAPER, inprocess=True)
    prof = cProfile.Profile(time.process_time)
    try:
        prof.enable()
        rate = _step_env(env, steps, np.random.default_rng(0))
        prof.disable()
    finally:
        env.close()
    stats = pstats.Stats(prof).stats  # type: ignore[attr-defined]
    found: dict[str, Any] = {}
    wanted = {"step (vehicle.py)": ("vehicle.py", "step"), "render (camera.py)": ("camera.py", "render"),
              "observe (observer.py)": ("observer.py", "observe"), "_run_frame (server.py)": ("server.py", "_run_frame"),
              "_end_frame (server.py)": ("server.py", "_end_frame"), "drain (inprocess.py)": ("inprocess.py", "drain"),
              "send_velocity_body (mavlink_link.py)": ("mavlink_link.py", "send_velocity_body"),
              "step (gym_env.py)": ("gym_env.py", "step")}
    for (file, _, name), row in stats.items():
        for label, (fname, fn) in wanted.items():
            if file.endswith(fname) and name == fn:
                found[label] = round(1000 * row[3] / steps, 3)  # cumulative seconds -> ms per env step
    whole = found.get("step (gym_env.py)", 0.0)
    shares = {k: round(v / whole, 3) for k, v in found.items()} if whole else {}
    return {"cpu_ms_per_step": found, "share_of_step": shares, "rates_under_profile": rate}


class _CpuTimer:
    """Wraps functions so that each call's CPU time is added to its label (restored on exit)."""

    def __init__(self, targets: dict[str, tuple[Any, str]]) -> None:
        self.targets = targets
        self.cpu_s: dict[str, float] = dict.fromkeys(targets, 0.0)
        self._saved: list[tuple[Any, str, Any]] = []

    def __enter__(self) -> _CpuTimer:
        for label, (owner, name) in self.targets.items():
            original = getattr(owner, name)
            self._saved.append((owner, name, original))

            def timed(*args: Any, _f: Any = original, _label: str = label, **kwargs: Any) -> Any:
                t0 = time.process_time()
                try:
                    return _f(*args, **kwargs)
                finally:
                    self.cpu_s[_label] += time.process_time() - t0

            setattr(owner, name, timed)
        return self

    def __exit__(self, *exc: object) -> None:
        for owner, name, original in reversed(self._saved):
            setattr(owner, name, original)


def floor(steps: int) -> dict[str, Any]:
    """The work no env of this task can skip, measured inside the in-process env: each step's
    12 FDM steps (flight controller + JSBSim), its camera image (render + pixel noise) and the
    pad detection, in CPU ms per env step; the rest of the step is glue (session, MAVLink
    semantics, telemetry, observation). ``bound_steps_per_s_on_2_idle_cores``: what 2 cores
    would give if the glue and the inter-process hand-over cost nothing."""
    import sitl.camera_feed
    import sitl.vehicle
    from companion.vision.perception import PadDetector

    cfg = load_companion_config(PAPER)
    env = LandingEnv(2, cfg, config_path=PAPER, inprocess=True)
    parts = {"vehicle_12_fdm_steps": (sitl.vehicle.SimVehicle, "step"), "render_and_noise": (sitl.camera_feed, "render_frame"),
             "pad_detection": (PadDetector, "detect")}
    try:
        _step_env(env, 100, np.random.default_rng(1))  # warm
        with _CpuTimer(parts) as timer:
            rate = _step_env(env, steps, np.random.default_rng(0))
    finally:
        env.close()
    ms = {k: round(1000 * v / steps, 3) for k, v in timer.cpu_s.items()}
    work = sum(ms.values())
    return {"cpu_ms_per_step": ms, "work_ms_per_step": round(work, 3), "whole_step_ms": rate["cpu_ms_per_step"],
            "glue_ms_per_step": round(rate["cpu_ms_per_step"] - work, 3),
            "bound_steps_per_s_on_2_idle_cores": round(2 * 1000 / work, 1)}


def batched(n_envs: int, workers: int, steps: int) -> dict[str, Any]:
    """``n_envs`` batched envs in ``workers`` processes (1: all in this process, no pipe): total
    wall-clock steps per second, and the CPU seconds of every process (ours and the workers')."""
    venv = make_vec_env(2, load_companion_config(PAPER), n_envs, PAPER, batched=True, workers=workers)
    rng = np.random.default_rng(0)
    try:
        venv.seed(0)
        venv.reset()
        pids = [p.pid for p in getattr(venv, "processes", [])]
        rounds = max(1, steps // n_envs)
        t0, c0, w0 = time.perf_counter(), time.process_time(), _cpu_s(pids)
        for _ in range(rounds):
            venv.step(rng.uniform(-1, 1, (n_envs, 2)).astype(np.float32))  # auto-resets
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0 + _cpu_s(pids) - w0
        return {**_rates(rounds * n_envs, wall, cpu), "processes": max(1, len(pids)), "env_steps": rounds * n_envs,
                "wall_s": round(wall, 2), "cpu_s_all_processes": round(cpu, 2)}
    finally:
        venv.close()


def _batched_worker(n_envs: int, steps: int, seed: int, queue: Any) -> None:
    """A child process: one batch stepped on its own; its CPU ms per env step goes back on ``queue``."""
    os.environ["OMP_NUM_THREADS"] = "1"
    from companion.rl.batched_env import BatchedLandingEnv

    env = BatchedLandingEnv(n_envs, 2, load_companion_config(PAPER), config_path=PAPER)
    rng = np.random.default_rng(seed)
    try:
        env.seed(seed)
        env.reset()
        rounds = max(1, steps // n_envs)
        t0, c0 = time.perf_counter(), time.process_time()
        for _ in range(rounds):
            env.step(rng.uniform(-1, 1, (n_envs, 2)).astype(np.float32))
        queue.put(_rates(rounds * n_envs, time.perf_counter() - t0, time.process_time() - c0))
    finally:
        env.close()


def batched_side_by_side(processes: int, n_envs: int, steps: int) -> dict[str, Any]:
    """``processes`` batches of ``n_envs``, each stepped by a process of its own with no pipe: the
    CPU ms per step when that many of our processes share the cores, beside ``batched`` in as
    many workers (the same plus the pipe's hand-over)."""
    import multiprocessing as mp

    ctx = mp.get_context("forkserver")
    queue = ctx.Queue()
    procs = [ctx.Process(target=_batched_worker, args=(n_envs, steps, 100 * k, queue)) for k in range(processes)]
    for proc in procs:
        proc.start()
    rates = [queue.get(timeout=600) for _ in procs]
    for proc in procs:
        proc.join()
    cpu_ms = sum(r["cpu_ms_per_step"] for r in rates) / processes
    return {"cpu_ms_per_step": round(cpu_ms, 3), "steps_per_s_per_idle_core": round(1000 / cpu_ms, 1),
            "steps_per_s_each": [r["steps_per_s"] for r in rates], "processes": processes}


def batched_floor(n_envs: int, steps: int) -> dict[str, Any]:
    """Where a batched step's CPU time goes (8 envs in this process): the work of ``floor``
    (vehicle, image, detection), the rest of the vehicle's own handling (setpoints, telemetry
    values, episode resets with their new JSBSim instance), and what is left (the vec env's
    arithmetic for all envs, Python's loop). Each wrapped call costs the timer a little too."""
    import companion.rl.direct_sitl as direct
    import sitl.vehicle
    from companion.rl.batched_env import BatchedLandingEnv
    from companion.rl.landing_lane import LandingLane
    from companion.vision.perception import PadDetector

    env = BatchedLandingEnv(n_envs, 2, load_companion_config(PAPER), config_path=PAPER)
    parts = {"vehicle_12_fdm_steps": (sitl.vehicle.SimVehicle, "step"), "render_and_noise": (direct, "render_frame"),
             "pad_detection": (PadDetector, "detect"), "setpoint_to_vehicle": (direct.DirectSitl, "command_velocity"),
             "telemetry_values": (direct.DirectSitl, "_fold"),
             "episode_starts_with_their_frames": (LandingLane, "begin")}  # overlaps the three above
    rng = np.random.default_rng(0)
    rounds = max(1, steps // n_envs)
    try:
        env.seed(0)
        env.reset()
        for _ in range(20):  # warm
            env.step(rng.uniform(-1, 1, (n_envs, 2)).astype(np.float32))
        with _CpuTimer(parts) as timer:
            c0 = time.process_time()
            for _ in range(rounds):
                env.step(rng.uniform(-1, 1, (n_envs, 2)).astype(np.float32))
            whole = time.process_time() - c0
    finally:
        env.close()
    n = rounds * n_envs
    ms = {k: round(1000 * v / n, 3) for k, v in timer.cpu_s.items()}
    work = ms["vehicle_12_fdm_steps"] + ms["render_and_noise"] + ms["pad_detection"]
    return {"cpu_ms_per_step": ms, "work_ms_per_step": round(work, 3), "whole_step_ms": round(1000 * whole / n, 3),
            "rest_ms_per_step": round(1000 * whole / n - work, 3),
            "work_share": round(work / (1000 * whole / n), 3)}


def interleaved(rounds: int, steps: int, n_envs: int = 8) -> dict[str, Any]:
    """The in-process env and a batch of ``n_envs`` in this process, stepped in turns (``rounds``
    times ``steps`` env steps each): on a machine whose load comes and goes, both meet the same
    load, so the ratio of their CPU ms per step (medians over the rounds) is the batched env's
    own gain."""
    from companion.rl.batched_env import BatchedLandingEnv

    cfg = load_companion_config(PAPER)
    single_env = LandingEnv(2, cfg, config_path=PAPER, inprocess=True)
    batch = BatchedLandingEnv(n_envs, 2, cfg, config_path=PAPER)
    rng = np.random.default_rng(0)
    ms: dict[str, list[float]] = {"inprocess_env": [], "batched": []}
    try:
        batch.seed(0)
        batch.reset()
        for _ in range(rounds):
            ms["inprocess_env"].append(_step_env(single_env, steps, rng)["cpu_ms_per_step"])
            c0 = time.process_time()
            for _ in range(max(1, steps // n_envs)):
                batch.step(rng.uniform(-1, 1, (n_envs, 2)).astype(np.float32))
            ms["batched"].append(round(1000 * (time.process_time() - c0) / (max(1, steps // n_envs) * n_envs), 3))
    finally:
        single_env.close()
        batch.close()
    median = {k: float(np.median(v)) for k, v in ms.items()}
    return {"cpu_ms_per_step_rounds": ms, "cpu_ms_per_step_median": median,
            "inprocess_over_batched": round(median["inprocess_env"] / median["batched"], 3)}


PARTS: dict[str, Any] = {
    "mavlink_env": lambda steps: single(False, steps),
    "inprocess_env": lambda steps: single(True, steps),
    "inprocess_2_workers": lambda steps: vectorised(2, 2 * steps),
    "inprocess_2_side_by_side": lambda steps: side_by_side(2, steps),
    "inprocess_8_envs_in_2_workers": lambda steps: vectorised(8, 2 * steps, workers=2),
    "profile": lambda steps: profile(max(300, steps // 3)),
    "floor": floor,
    "batched_8_envs_in_1_process": lambda steps: batched(8, 1, 2 * steps),
    "batched_8_envs_in_2_processes": lambda steps: batched(8, 2, 2 * steps),
    "batched_2x4_side_by_side": lambda steps: batched_side_by_side(2, 4, steps),
    "batched_floor": lambda steps: batched_floor(8, steps),
    "interleaved": lambda steps: interleaved(7, max(200, steps // 5)),
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer steps (about a minute)")
    parser.add_argument("--steps", type=int, default=None, help="steps per measurement")
    parser.add_argument("--parts", default=",".join(PARTS), help=f"which measurements, of {','.join(PARTS)}")
    args = parser.parse_args()
    parts = [p for p in args.parts.split(",") if p]
    unknown = sorted(set(parts) - set(PARTS))
    if unknown:
        parser.error(f"unknown parts {unknown}; known: {list(PARTS)}")
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    steps = args.steps or (600 if args.quick else 3000)
    ref = machine_ref_rt()
    load0 = os.getloadavg()[0]
    result: dict[str, Any] = {"bench": "rl_env_speed", "steps": steps}
    result.update({name: PARTS[name](steps) for name in parts})
    result.update({
        "goal_steps_per_s": GOAL_STEPS_PER_S, "goal_machine_ref_rt": GOAL_MACHINE_REF_RT,
        "goal_steps_per_s_at_this_machine_ref": round(GOAL_STEPS_PER_S * ref / GOAL_MACHINE_REF_RT), "cores": os.cpu_count(),
        "load_avg_1min": [round(load0, 2), round(os.getloadavg()[0], 2)],
        "machine_ref_rt": round(ref, 1),
    })
    print(json.dumps(result))


if __name__ == "__main__":
    main()
