"""CPU seconds per step of LandingEnv(inprocess=True), random 2-axis actions, paper config."""
import sys, time, json, cProfile, pstats, io
from pathlib import Path
import numpy as np
from companion.config import load_companion_config
from companion.rl.gym_env import LandingEnv
cfg_path = Path("configs/paper.toml")
env = LandingEnv(2, load_companion_config(cfg_path), config_path=cfg_path, inprocess=True)
rng = np.random.default_rng(0)
env.reset(seed=1)
steps = int(sys.argv[1]); prof = len(sys.argv) > 2
def run():
    for _ in range(steps):
        _, _, term, trunc, _ = env.step(rng.uniform(-1, 1, 2).astype(np.float32))
        if term or trunc:
            env.reset()
if prof:
    pr = cProfile.Profile(); pr.enable(); run(); pr.disable()
    s = io.StringIO(); pstats.Stats(pr, stream=s).sort_stats("tottime").print_stats(25); print(s.getvalue())
else:
    t0 = time.process_time(); run(); print(json.dumps({"cpu_ms_per_step": round(1000 * (time.process_time() - t0) / steps, 3)}))
env.close()
