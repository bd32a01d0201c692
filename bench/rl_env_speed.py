"""How many landing-env steps per second: the MAVLink env, the in-process env, and the
in-process env in 2 worker processes (stable-baselines3 ``SubprocVecEnv``); and where one
in-process step's time goes (a cProfile of the same stepping).

Random actions in the 2-action task on the calibrated task (``configs/paper.toml``), episodes
reset as they end, as PPO steps an env. Goal: 2,000 env steps/s in total on a 2-core machine.

    python bench/rl_env_speed.py [--quick] [--steps N]
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

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
from machine_ref import machine_ref_rt  # noqa: E402

from companion.config import load_companion_config  # noqa: E402
from companion.rl.gym_env import LandingEnv  # noqa: E402
from companion.rl.vec_env import make_vec_env  # noqa: E402

PAPER = REPO / "configs" / "paper.toml"
GOAL_STEPS_PER_S = 2000


def _step_env(env: LandingEnv, steps: int, rng: np.random.Generator) -> float:
    """Steps per second of one env over ``steps`` steps (resetting as episodes end)."""
    env.reset(seed=0)
    t0 = time.perf_counter()
    for _ in range(steps):
        _, _, terminated, truncated, _ = env.step(rng.uniform(-1, 1, 2).astype(np.float32))
        if terminated or truncated:
            env.reset()
    return steps / (time.perf_counter() - t0)


def single(inprocess: bool, steps: int) -> float:
    cfg = load_companion_config(PAPER)
    env = LandingEnv(2, cfg, config_path=PAPER, inprocess=inprocess)
    try:
        return _step_env(env, steps, np.random.default_rng(0))
    finally:
        env.close()


def vectorised(n_envs: int, steps: int) -> float:
    """Total steps per second of ``n_envs`` in-process envs in worker processes."""
    venv = make_vec_env(2, load_companion_config(PAPER), n_envs, PAPER)
    rng = np.random.default_rng(0)
    try:
        venv.seed(0)
        venv.reset()
        rounds = max(1, steps // n_envs)
        t0 = time.perf_counter()
        for _ in range(rounds):
            venv.step(rng.uniform(-1, 1, (n_envs, 2)).astype(np.float32))  # auto-resets
        return rounds * n_envs / (time.perf_counter() - t0)
    finally:
        venv.close()


def profile(steps: int) -> dict[str, float]:
    """Milliseconds per in-process step in the main parts, from cProfile's cumulative times."""
    cfg = load_companion_config(PAPER)
    env = LandingEnv(2, cfg, config_path=PAPER, inprocess=True)
    prof = cProfile.Profile()
    try:
        prof.enable()
        rate = _step_env(env, steps, np.random.default_rng(0))
        prof.disable()
    finally:
        env.close()
    stats = pstats.Stats(prof).stats  # type: ignore[attr-defined]
    found = {}
    wanted = {"step (vehicle.py)": ("vehicle.py", "step"), "render (camera.py)": ("camera.py", "render"),
              "observe (observer.py)": ("observer.py", "observe"), "_run_frame (server.py)": ("server.py", "_run_frame"),
              "_end_frame (server.py)": ("server.py", "_end_frame"), "drain (inprocess.py)": ("inprocess.py", "drain"),
              "send_velocity_body (mavlink_link.py)": ("mavlink_link.py", "send_velocity_body"),
              "step (gym_env.py)": ("gym_env.py", "step")}
    for (file, _, name), row in stats.items():
        for label, (fname, fn) in wanted.items():
            if file.endswith(fname) and name == fn:
                found[label] = round(1000 * row[3] / steps, 3)  # cumulative seconds -> ms per env step
    found["steps_per_s_under_profile"] = round(rate, 1)
    return found


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer steps (about a minute)")
    parser.add_argument("--steps", type=int, default=None, help="steps per measurement")
    args = parser.parse_args()
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    steps = args.steps or (600 if args.quick else 3000)
    ref = machine_ref_rt()
    load0 = os.getloadavg()[0]
    result = {
        "bench": "rl_env_speed", "steps": steps,
        "mavlink_env_steps_per_s": round(single(False, steps), 1),
        "inprocess_env_steps_per_s": round(single(True, steps), 1),
        "inprocess_2_workers_steps_per_s": round(vectorised(2, 2 * steps), 1),
        "profile_ms_per_step": profile(max(300, steps // 3)),
        "goal_steps_per_s": GOAL_STEPS_PER_S, "cores": os.cpu_count(),
        "load_avg_1min": [round(load0, 2), round(os.getloadavg()[0], 2)],
        "machine_ref_rt": round(ref, 1),
    }
    print(json.dumps(result))


if __name__ == "__main__":
    main()
