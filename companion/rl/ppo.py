"""The paper's reinforcement-learning baseline: PPO on the sparse landing reward.

stable-baselines3's PPO (``MlpPolicy``, CPU, seeded) learns in :class:`LandingEnv` for a number
of *episodes* (the paper: 1000), with 2, 3 or 4 actions. Training episode ``i`` starts from
the SITL's seed ``seed + i`` (one env); the final model is then flown deterministically on the
held-out starts of ``col eval`` (seeds ``100_000 + i``). Everything measured goes to one JSON
file. A run folder is resumable: the model is saved after every PPO update with the number of
episodes logged by then, and a run started again on the folder continues from there.
"""

from __future__ import annotations

import json
import platform
import statistics
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import IO, Any, Protocol

import numpy as np
import stable_baselines3
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecEnv

from companion.config import CompanionConfig
from companion.errors import ConfigError
from companion.rl.gym_env import LandingEnv
from companion.rl.run_config import record_run_config, task_summary
from companion.rl.vec_env import make_vec_env
from companion.statistics import wilson_interval

EVAL_SEED = 100_000
EpisodeHook = Callable[[dict[str, Any]], None]
ModelMaker = Callable[[Any], PPO]
CHECKPOINT = "checkpoint.zip"
CHECKPOINT_STATE = "checkpoint.json"


@dataclass(frozen=True)
class PpoRunSettings:
    """What every PPO run here is set by (the baseline's and the fine-tuning's): the actions, the
    episodes and their seeds, PPO's hyperparameters (stable-baselines3's defaults unless set; the
    paper does not give its own) and where the envs run. ``log_std_init`` (the initial log
    standard deviation of the Gaussian policy) and ``ent_coef`` are stable-baselines3's 0 and 0."""

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
    log_std_init: float = 0.0
    ent_coef: float = 0.0
    n_envs: int = 1
    inprocess: bool = True

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
        if not -5.0 <= self.log_std_init <= 1.0 or self.ent_coef < 0.0 or self.n_envs < 1:
            raise ConfigError(f"log_std_init must be in [-5, 1], ent_coef >= 0 and n_envs >= 1, got "
                              f"{self.log_std_init}, {self.ent_coef}, {self.n_envs}")


@dataclass(frozen=True)
class PpoSettings(PpoRunSettings):
    """One PPO baseline run: :class:`PpoRunSettings` and whether advantages are normalised per
    minibatch (stable-baselines3: yes)."""

    normalize_advantage: bool = True


class EpisodeLog(BaseCallback):
    """Keeps each finished training episode's outcome and stops after ``max_episodes``."""

    def __init__(self, max_episodes: int, on_episode: EpisodeHook | None = None,
                 episodes: list[dict[str, Any]] | None = None, checkpoint_dir: Path | None = None) -> None:
        super().__init__()
        self.max_episodes = max_episodes
        self.on_episode = on_episode
        self.episodes: list[dict[str, Any]] = list(episodes or [])
        self.checkpoint_dir = checkpoint_dir
        self._wall0 = time.monotonic() - (self.episodes[-1]["wall_s"] if self.episodes else 0.0)

    def _on_rollout_end(self) -> None:
        """After each rollout (just before PPO's update from it) the model so far, for resuming."""
        if self.checkpoint_dir is not None:
            save_checkpoint(self.model, self.checkpoint_dir, len(self.episodes))

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


def make_model(env: LandingEnv | VecEnv, settings: PpoSettings) -> PPO:
    """A fresh, seeded PPO with stable-baselines3's MLP policy, on the CPU."""
    return PPO("MlpPolicy", env, n_steps=settings.n_steps, batch_size=settings.batch_size,
               n_epochs=settings.n_epochs, learning_rate=settings.learning_rate, gamma=settings.gamma,
               ent_coef=settings.ent_coef, normalize_advantage=settings.normalize_advantage,
               policy_kwargs={"log_std_init": settings.log_std_init},
               seed=settings.seed, device="cpu", verbose=0)


def save_checkpoint(model: BaseAlgorithm, folder: Path, episodes_done: int) -> None:
    """The model and how many logged episodes it has seen, each written atomically."""
    model.save(folder / "checkpoint.tmp.zip")
    (folder / "checkpoint.tmp.zip").replace(folder / CHECKPOINT)
    (folder / "checkpoint.tmp.json").write_text(json.dumps({"episodes": episodes_done}))
    (folder / "checkpoint.tmp.json").replace(folder / CHECKPOINT_STATE)


def load_checkpoint(folder: Path, env: LandingEnv | VecEnv,
                    settings: Any) -> tuple[PPO, list[dict[str, Any]]] | None:
    """The folder's saved model and the episodes it had seen (the log cut back to them), or None."""
    state_file, log_file = folder / CHECKPOINT_STATE, folder / "train_episodes.jsonl"
    if not state_file.exists() or not (folder / CHECKPOINT).exists():
        return None
    done = int(json.loads(state_file.read_text())["episodes"])
    lines = log_file.read_text().splitlines() if log_file.exists() else []
    if len(lines) < done:
        raise ConfigError(f"{log_file} has {len(lines)} episodes but the checkpoint saw {done}: not resumable")
    episodes = [json.loads(line) for line in lines[:done]]
    log_file.write_text("".join(line + "\n" for line in lines[:done]))
    model = PPO.load(folder / CHECKPOINT, env=env, device="cpu")
    model.set_random_seed(settings.seed + done)  # training starts continue at seed + episodes done
    return model, episodes


def train(env: LandingEnv | VecEnv, settings: Any, on_episode: EpisodeHook | None = None,
          folder: Path | None = None, make: ModelMaker | None = None,
          on_load: Callable[[PPO], PPO] | None = None) -> tuple[PPO, list[dict[str, Any]]]:
    """Train for ``settings.episodes`` episodes; the model and one record per episode. With a
    ``folder``, checkpoint after each update and continue from the folder's checkpoint. ``make``
    builds a fresh model (default :func:`make_model`); ``on_load`` finishes a loaded one."""
    resumed = load_checkpoint(folder, env, settings) if folder is not None else None
    if resumed is not None:
        model, episodes = (on_load(resumed[0]) if on_load else resumed[0]), resumed[1]
    else:
        model, episodes = (make(env) if make else make_model(env, settings)), []
    log = EpisodeLog(settings.episodes, on_episode, episodes, folder)
    left = settings.episodes - len(episodes)
    if left > 0:
        max_steps = env.get_attr("max_steps")[0] if isinstance(env, VecEnv) else env.max_steps
        model.learn(total_timesteps=left * max_steps + settings.n_steps * settings.n_envs, callback=log,
                    reset_num_timesteps=resumed is None)
    return model, log.episodes


def train_in_folder(venv: VecEnv, settings: PpoRunSettings, out_dir: Path, on_episode: EpisodeHook | None = None,
                    make: ModelMaker | None = None, on_load: Callable[[PPO], PPO] | None = None,
                    ) -> tuple[PPO, list[dict[str, Any]], float]:
    """:func:`train` a run folder's model (resumed from its checkpoint), each episode a line of
    ``train_episodes.jsonl`` as soon as it ends, the model then in ``model.zip``; also the
    training's wall time in seconds (the log's, across resumes). Closes ``venv``."""
    try:
        wall0 = time.monotonic()
        with (out_dir / "train_episodes.jsonl").open("a") as log_file:
            model, episodes = train(venv, settings, _logged(log_file, on_episode), out_dir, make, on_load)
        train_s = float(episodes[-1]["wall_s"]) if episodes else time.monotonic() - wall0
        model.save(out_dir / "model.zip")
    finally:
        venv.close()
    return model, episodes, train_s


class Actor(Protocol):
    """What flies an evaluation: stable-baselines3's ``predict``."""

    def predict(self, observation: Any, *args: Any, **kwargs: Any) -> tuple[np.ndarray, Any]: ...


def fly(model: Actor, env: LandingEnv, seed: int, index: int = 0) -> dict[str, Any]:
    """One episode (number ``index``) of the model's deterministic policy from the start ``seed``."""
    obs, _ = env.reset(seed=seed)
    while True:
        action, _ = model.predict(obs, deterministic=True)
        obs, _, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            return _episode_record(index, info)


def evaluate_runs(model: Actor, env: LandingEnv, episodes: int, seed0: int = EVAL_SEED) -> list[dict[str, Any]]:
    """One record per held-out start ``seed0 + i``."""
    return [fly(model, env, seed0 + i, i) for i in range(episodes)]


def evaluate(model: Actor, env: LandingEnv, episodes: int, seed0: int = EVAL_SEED) -> dict[str, Any]:
    """Success rate on ``episodes`` held-out starts, reported as ``col eval`` reports it."""
    return summarise(evaluate_runs(model, env, episodes, seed0))


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


def learning_curve(episodes: list[dict[str, Any]], blocks: int = 10, size: int | None = None) -> list[dict[str, Any]]:
    """Training success rate (stochastic policy) in consecutive blocks of episodes (``blocks``
    of them, or blocks of ``size`` episodes)."""
    size = size or max(1, len(episodes) // blocks)
    curve = []
    for start in range(0, len(episodes), size):
        block = episodes[start:start + size]
        curve.append({"first_episode": start, "episodes": len(block),
                      "success_rate": round(sum(bool(r["success"]) for r in block) / len(block), 4)})
    return curve


def run_ppo(settings: PpoSettings, out_dir: Path, cfg: CompanionConfig | None = None,
            config_path: Path | None = None, on_episode: EpisodeHook | None = None,
            workers: int | None = None, batched: bool = False) -> dict[str, Any]:
    """Train, save ``model.zip`` and ``train_episodes.jsonl``, evaluate, write ``results.json``.
    A folder with ``results.json`` is done (returned as is); one with a checkpoint continues.
    Either only for the settings it was started with: others are refused first, so a finished
    run is never reported as the answer to a run with other options.
    ``workers``: processes the ``n_envs`` envs run in (default one per env); speed only, the
    episodes are the same (:mod:`companion.rl.grouped_vec_env`), so it is not a setting; nor is
    ``batched``: the training envs are :class:`~companion.rl.batched_env.BatchedLandingEnv`'s,
    the same episodes without the session (``workers`` processes, default this one)."""
    cfg = cfg or CompanionConfig()
    out_dir.mkdir(parents=True, exist_ok=True)
    _check_same_settings(out_dir, settings)
    if (out_dir / "results.json").exists():
        return dict(json.loads((out_dir / "results.json").read_text()))
    task = task_summary(record_run_config(out_dir, cfg, config_path))
    torch.set_num_threads(cfg.learner.torch_threads)
    venv = make_vec_env(settings.action_dims, cfg, settings.n_envs, config_path, inprocess=settings.inprocess,
                        workers=workers, batched=batched)
    model, episodes, train_s = train_in_folder(venv, settings, out_dir, on_episode)
    eval_env = LandingEnv(settings.action_dims, cfg, config_path=config_path, inprocess=settings.inprocess)
    try:
        wall1 = time.monotonic()
        report = evaluate(model, eval_env, settings.eval_episodes, settings.eval_seed)
        eval_s = time.monotonic() - wall1
    finally:
        eval_env.close()
    results = {**_results(settings, episodes, report, train_s, eval_s, out_dir), "task": task}
    (out_dir / "results.json").write_text(json.dumps(results, indent=1) + "\n")
    return results


def evaluate_checkpoint(out_dir: Path, cfg: CompanionConfig | None = None, config_path: Path | None = None,
                        episodes: int | None = None) -> dict[str, Any]:
    """An unfinished run's latest checkpoint on the held-out starts, as the final model would be
    flown; written to ``checkpoint_eval.json`` with the training episodes it had seen."""
    state = out_dir / CHECKPOINT_STATE
    if not state.exists():
        raise ConfigError(f"{out_dir} has no PPO checkpoint to evaluate (no {CHECKPOINT_STATE})")
    settings = PpoSettings(**json.loads((out_dir / "settings.json").read_text()))
    cfg = cfg or CompanionConfig()
    model = PPO.load(out_dir / CHECKPOINT, device="cpu")
    env = LandingEnv(settings.action_dims, cfg, config_path=config_path, inprocess=settings.inprocess)
    try:
        report = evaluate(model, env, episodes or settings.eval_episodes, settings.eval_seed)
    finally:
        env.close()
    result = {"train_episodes_seen": int(json.loads(state.read_text())["episodes"]), "eval": report}
    (out_dir / "checkpoint_eval.json").write_text(json.dumps(result, indent=1) + "\n")
    return result


def _check_same_settings(out_dir: Path, settings: PpoSettings) -> None:
    """A folder continues, or reports, only the run it was started for."""
    recorded = recorded_settings(out_dir)
    if recorded is None:
        (out_dir / "settings.json").write_text(json.dumps(asdict(settings)) + "\n")
        return
    refuse_other_settings(out_dir, {**asdict(PpoSettings()), **recorded}, asdict(settings))  # added since: defaults


def recorded_settings(out_dir: Path) -> dict[str, Any] | None:
    """The settings a run folder was started with: ``settings.json``, else those its
    ``results.json`` records (a finished run from before settings.json); None for a new folder."""
    if (out_dir / "settings.json").exists():
        return dict(json.loads((out_dir / "settings.json").read_text()))
    if (out_dir / "results.json").exists():
        return dict(json.loads((out_dir / "results.json").read_text()).get("settings", {}))
    return None


def refuse_other_settings(out_dir: Path, before: dict[str, Any], now: dict[str, Any]) -> None:
    """ConfigError naming each setting in which ``now`` differs from the run in ``out_dir``."""
    changed = [f"{name}: the run has {before.get(name)!r}, asked {now.get(name)!r}"
               for name in sorted(set(before) | set(now)) if before.get(name) != now.get(name)]
    if changed:
        state = "finished" if (out_dir / "results.json").exists() else "unfinished"
        raise ConfigError(f"{out_dir} holds a {state} run with other settings ({'; '.join(changed)}); "
                          "use another --out, or the run's own options to continue or show it")


def random_policy(action_dims: int, episodes: int, cfg: CompanionConfig | None = None,
                  config_path: Path | None = None, seed: int = 0,
                  on_episode: EpisodeHook | None = None) -> list[dict[str, Any]]:
    """Uniformly random actions in [-1, 1] on the training starts ``seed + i`` (what PPO's
    exploration meets at first): one record per episode."""
    rng = np.random.default_rng(seed)
    env = LandingEnv(action_dims, cfg or CompanionConfig(), config_path=config_path, inprocess=True)
    runs = []
    try:
        for i in range(episodes):
            env.reset(seed=seed + i)
            while True:
                _, _, terminated, truncated, info = env.step(rng.uniform(-1.0, 1.0, action_dims).astype(np.float32))
                if terminated or truncated:
                    break
            runs.append(_episode_record(i, info))
            if on_episode is not None:
                on_episode(runs[-1])
    finally:
        env.close()
    return runs


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
            "learning_curve_50": learning_curve(episodes, size=50),
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
