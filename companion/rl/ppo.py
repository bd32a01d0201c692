"""The paper's reinforcement-learning baseline: PPO on the sparse landing reward.

stable-baselines3's PPO (``MlpPolicy``, CPU, seeded) learns in :class:`LandingEnv` for a number
of *episodes* (the paper: 1000), with 2, 3 or 4 actions. Training episode ``i`` starts from
the SITL's seed ``seed + i``; the final model is then flown deterministically on the held-out
starts of ``col eval`` (seeds ``100_000 + i``). Everything measured goes to one JSON file.
"""

from __future__ import annotations

import json
import platform
import statistics
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import IO, Any

import numpy as np
import stable_baselines3
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback

from companion.config import CompanionConfig
from companion.errors import ConfigError
from companion.rl.gym_env import LandingEnv
from companion.statistics import wilson_interval

EVAL_SEED = 100_000
EpisodeHook = Callable[[dict[str, Any]], None]


@dataclass(frozen=True)
class PpoSettings:
    """One PPO baseline run. PPO's hyperparameters are stable-baselines3's defaults unless set
    (the paper does not give its own)."""

    action_dims: int = 2
    episodes: int = 1000
    eval_episodes: int = 100
    seed: int = 0
    eval_seed: int = EVAL_SEED
    n_steps: int = 2048
    batch_size: int = 64
    n_epochs: int = 10
    learning_rate: float = 3e-4
    gamma: float = 0.99

    def __post_init__(self) -> None:
        if self.action_dims not in (2, 3, 4):
            raise ConfigError(f"action_dims must be 2, 3 or 4, got {self.action_dims}")
        for name in ("episodes", "eval_episodes", "n_steps", "batch_size", "n_epochs"):
            if getattr(self, name) < 1:
                raise ConfigError(f"{name} must be at least 1, got {getattr(self, name)}")
        if self.n_steps < 2:
            raise ConfigError(f"n_steps must be at least 2 (PPO normalises advantages over a rollout), got {self.n_steps}")
        if not 0.0 < self.learning_rate < 1.0 or not 0.0 < self.gamma <= 1.0:
            raise ConfigError(f"learning_rate must be in (0, 1) and gamma in (0, 1], got {self.learning_rate}, {self.gamma}")
        if self.seed < 0 or self.eval_seed < 0:
            raise ConfigError("seeds must be >= 0")


class EpisodeLog(BaseCallback):
    """Keeps each finished training episode's outcome and stops after ``max_episodes``."""

    def __init__(self, max_episodes: int, on_episode: EpisodeHook | None = None) -> None:
        super().__init__()
        self.max_episodes = max_episodes
        self.on_episode = on_episode
        self.episodes: list[dict[str, Any]] = []
        self._wall0 = time.monotonic()

    def _on_step(self) -> bool:
        for done, info in zip(self.locals["dones"], self.locals["infos"]):
            if done:
                record = _episode_record(len(self.episodes), info)
                record["wall_s"] = round(time.monotonic() - self._wall0, 3)
                self.episodes.append(record)
                if self.on_episode is not None:
                    self.on_episode(record)
        return len(self.episodes) < self.max_episodes


def _episode_record(index: int, info: dict[str, Any]) -> dict[str, Any]:
    keys = ("seed", "steps", "outcome", "success", "touchdown_distance_m")
    return {"episode": index, **{k: info.get(k) for k in keys}}


def make_model(env: LandingEnv, settings: PpoSettings) -> PPO:
    """A fresh, seeded PPO with stable-baselines3's MLP policy, on the CPU."""
    return PPO("MlpPolicy", env, n_steps=settings.n_steps, batch_size=settings.batch_size,
               n_epochs=settings.n_epochs, learning_rate=settings.learning_rate, gamma=settings.gamma,
               seed=settings.seed, device="cpu", verbose=0)


def train(env: LandingEnv, settings: PpoSettings,
          on_episode: EpisodeHook | None = None) -> tuple[PPO, list[dict[str, Any]]]:
    """Train for ``settings.episodes`` episodes; the model and one record per episode."""
    model = make_model(env, settings)
    log = EpisodeLog(settings.episodes, on_episode)
    model.learn(total_timesteps=settings.episodes * env.max_steps + settings.n_steps, callback=log)
    return model, log.episodes


def fly(model: PPO, env: LandingEnv, seed: int, index: int = 0) -> dict[str, Any]:
    """One episode (number ``index``) of the model's deterministic policy from the start ``seed``."""
    obs, _ = env.reset(seed=seed)
    while True:
        action, _ = model.predict(obs, deterministic=True)
        obs, _, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            return _episode_record(index, info)


def evaluate(model: PPO, env: LandingEnv, episodes: int, seed0: int = EVAL_SEED) -> dict[str, Any]:
    """Success rate on ``episodes`` held-out starts, reported as ``col eval`` reports it."""
    runs = [fly(model, env, seed0 + i, i) for i in range(episodes)]
    return summarise(runs)


def summarise(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """Success rate with its 95 % Wilson interval, touchdowns, timeouts and fence exits."""
    n, k = len(runs), sum(bool(r["success"]) for r in runs)
    lo, hi = wilson_interval(k, n)
    distances = [r["touchdown_distance_m"] for r in runs if r["touchdown_distance_m"] is not None]
    return {
        "episodes": n, "successes": k, "success_rate": round(k / n, 4) if n else 0.0,
        "ci95": [round(lo, 4), round(hi, 4)],
        "touchdown_distance_m_median": round(statistics.median(distances), 3) if distances else None,
        "touchdowns": len(distances),
        "timeouts": sum(r["outcome"] == "timeout" for r in runs),
        "fence": sum(r["outcome"] == "fence" for r in runs),
        "link_lost": sum(r["outcome"] == "link_lost" for r in runs),
        "steps_mean": round(float(np.mean([r["steps"] for r in runs])), 1) if runs else 0.0,
    }


def learning_curve(episodes: list[dict[str, Any]], blocks: int = 10) -> list[dict[str, Any]]:
    """Training success rate (stochastic policy) in consecutive blocks of episodes."""
    size = max(1, len(episodes) // blocks)
    curve = []
    for start in range(0, len(episodes), size):
        block = episodes[start:start + size]
        curve.append({"first_episode": start, "episodes": len(block),
                      "success_rate": round(sum(bool(r["success"]) for r in block) / len(block), 4)})
    return curve


def run_ppo(settings: PpoSettings, out_dir: Path, cfg: CompanionConfig | None = None,
            config_path: Path | None = None, on_episode: EpisodeHook | None = None) -> dict[str, Any]:
    """Train, save ``model.zip`` and ``train_episodes.jsonl``, evaluate, write ``results.json``."""
    cfg = cfg or CompanionConfig()
    out_dir.mkdir(parents=True, exist_ok=True)
    torch.set_num_threads(cfg.learner.torch_threads)
    env = LandingEnv(settings.action_dims, cfg, config_path=config_path)
    try:
        with (out_dir / "train_episodes.jsonl").open("w") as log_file:
            wall0 = time.monotonic()
            model, episodes = train(env, settings, _logged(log_file, on_episode))
            train_s = time.monotonic() - wall0
        model.save(out_dir / "model.zip")
        wall1 = time.monotonic()
        report = evaluate(model, env, settings.eval_episodes, settings.eval_seed)
        eval_s = time.monotonic() - wall1
    finally:
        env.close()
    results = _results(settings, episodes, report, train_s, eval_s, out_dir)
    (out_dir / "results.json").write_text(json.dumps(results, indent=1) + "\n")
    return results


def _results(settings: PpoSettings, episodes: list[dict[str, Any]], report: dict[str, Any],
             train_s: float, eval_s: float, out_dir: Path) -> dict[str, Any]:
    steps = sum(int(r["steps"]) for r in episodes)
    return {
        "settings": asdict(settings),
        "train": {
            "episodes": len(episodes), "steps": steps,
            "successes": sum(bool(r["success"]) for r in episodes),
            "wall_s": round(train_s, 1),
            "wall_s_per_1000_episodes": round(1000 * train_s / max(1, len(episodes)), 1),
            "learning_curve": learning_curve(episodes),
        },
        "eval": {**report, "seed0": settings.eval_seed, "wall_s": round(eval_s, 1)},
        "model": str(out_dir / "model.zip"),
        "versions": {"stable_baselines3": stable_baselines3.__version__, "torch": torch.__version__,
                     "python": platform.python_version()},
    }


def _logged(log_file: IO[str], on_episode: EpisodeHook | None) -> EpisodeHook:
    """Each training episode as a JSON line as soon as it ends (watchable, kept on a crash)."""

    def hook(record: dict[str, Any]) -> None:
        log_file.write(json.dumps(record) + "\n")
        log_file.flush()
        if on_episode is not None:
            on_episode(record)

    return hook
