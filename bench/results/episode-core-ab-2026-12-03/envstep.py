"""CPU milliseconds per step of LandingEnv(inprocess=True), random 2-axis actions, paper config.

Usage: envstep.py STEPS [profile]  (with ``profile``: cProfile's 25 costliest functions instead)
"""

import cProfile
import io
import json
import pstats
import sys
import time
from pathlib import Path

import numpy as np

from companion.config import load_companion_config
from companion.rl.gym_env import LandingEnv


def run(env: LandingEnv, steps: int, rng: np.random.Generator) -> None:
    for _ in range(steps):
        _, _, term, trunc, _ = env.step(rng.uniform(-1, 1, 2).astype(np.float32))
        if term or trunc:
            env.reset()


def main(steps: int, profile: bool) -> None:
    cfg_path = Path("configs/paper.toml")
    env = LandingEnv(2, load_companion_config(cfg_path), config_path=cfg_path, inprocess=True)
    rng = np.random.default_rng(0)
    env.reset(seed=1)
    if profile:
        pr = cProfile.Profile()
        pr.enable()
        run(env, steps, rng)
        pr.disable()
        out = io.StringIO()
        pstats.Stats(pr, stream=out).sort_stats("tottime").print_stats(25)
        print(out.getvalue())
    else:
        t0 = time.process_time()
        run(env, steps, rng)
        print(json.dumps({"cpu_ms_per_step": round(1000 * (time.process_time() - t0) / steps, 3)}))
    env.close()


if __name__ == "__main__":
    main(int(sys.argv[1]), len(sys.argv) > 2)
