"""Reinforcement learning after the Cycle-of-Learning: PPO fine-tuning of a human-trained policy.

The paper's future work (and the authors' later Cycle-of-Learning papers) continue training the
policy learned from the person with reinforcement learning. Here PPO's actor *is* the CoL
checkpoint's network (15-130-72-40-4, ReLU, tanh, its own input normalisation): the mean of the
Gaussian policy is the network's output reordered to the env's axes, so before any update the
deterministic actor flies exactly as the checkpoint does. The critic is a separate 64-64 tanh
network (stable-baselines3's default). The loss is PPO's on the sparse success reward plus a
behaviour-cloning term on the person's dataset: ``w_k * MSE(actor(obs), action)`` over a
minibatch of the dataset at every PPO minibatch step, ``w_k = bc_weight * 0.5 ** (k /
bc_half_life)`` after ``k`` PPO updates, so the person's example anchors the policy at first and
gives way to the reward.

How the term joins the loss: a hook runs before each of PPO's optimiser steps and adds the term's
gradient to PPO's (already norm-clipped) gradient, so each step follows the sum of both losses.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.vec_env import VecEnv
from torch import nn

from companion.config import CompanionConfig, LearnerConfig
from companion.errors import ConfigError
from companion.learning.checkpoint import load_checkpoint, save_checkpoint
from companion.learning.dataset import discarded_episodes, load_csv
from companion.learning.policy import PolicyNet, PolicySnapshot
from companion.rl.gym_env import LandingEnv
from companion.rl.ppo import (
    EpisodeHook,
    PpoRunSettings,
    evaluate,
    recorded_settings,
    refuse_other_settings,
    train_in_folder,
)
from companion.rl.run_config import record_run_config, task_summary
from companion.rl.vec_env import make_vec_env

ENV_FROM_POLICY = (1, 0, 3, 2)
"""The env's actions (pitch, roll, throttle, yaw) as indices into the policy's outputs
(roll, pitch, yaw, throttle: ``companion.learning.policy.ACTION_NAMES``)."""
POLICY_FROM_ENV = (1, 0, 3, 2)  # the same swap undoes itself


@dataclass(frozen=True)
class FinetuneSettings(PpoRunSettings):
    """One fine-tuning run (4 actions): :class:`~companion.rl.ppo.PpoRunSettings` and the
    behaviour-cloning term's. Our choices, not the paper's: a small initial action noise
    (``log_std_init`` -1.5: a standard deviation of 0.22 stick around the human-trained actor,
    not stable-baselines3's 1), a lower learning rate than PPO's default, and shorter rollouts,
    so that a few dozen episodes make several updates."""

    action_dims: int = 4
    episodes: int = 50
    n_steps: int = 512
    learning_rate: float = 1e-4
    log_std_init: float = -1.5
    bc_weight: float = 1.0
    bc_half_life: float = 10.0
    bc_batch_size: int = 64

    def __post_init__(self) -> None:
        if self.action_dims != 4:
            raise ConfigError("fine-tuning flies all four axes, as the checkpoint's policy does")
        super().__post_init__()
        if self.bc_batch_size < 1:
            raise ConfigError(f"bc_batch_size must be at least 1, got {self.bc_batch_size}")
        if self.bc_weight < 0.0 or self.bc_half_life <= 0.0:
            raise ConfigError(f"bc_weight must be >= 0 and bc_half_life > 0, got {self.bc_weight}, {self.bc_half_life}")


# ====================================================================== the actor-critic
class CoLActor(nn.Module):
    """The checkpoint's network as PPO's actor: its tanh outputs in the env's axis order."""

    def __init__(self, snapshot: PolicySnapshot) -> None:
        super().__init__()
        self.net = PolicyNet.from_snapshot(snapshot)
        self.register_buffer("order", torch.tensor(ENV_FROM_POLICY))

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return self.net(obs)[..., self.order]


class ActorAndCritic(nn.Module):
    """stable-baselines3's "mlp extractor" slot: the actor's latent is already the action mean."""

    def __init__(self, snapshot: PolicySnapshot, hidden: int = 64) -> None:
        super().__init__()
        self.actor = CoLActor(snapshot)
        obs_dim = snapshot.obs_dim
        self.critic = nn.Sequential(nn.Linear(obs_dim, hidden), nn.Tanh(), nn.Linear(hidden, hidden), nn.Tanh())
        self.latent_dim_pi = len(ENV_FROM_POLICY)
        self.latent_dim_vf = hidden

    def forward(self, features: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.actor(features), self.critic(features)

    def forward_actor(self, features: torch.Tensor) -> torch.Tensor:
        return self.actor(features)

    def forward_critic(self, features: torch.Tensor) -> torch.Tensor:
        return self.critic(features)


class CoLPolicy(ActorCriticPolicy):
    """PPO's policy around a CoL checkpoint's network (no orthogonal re-initialisation: the
    actor keeps the person-trained weights; no extra action layer: the mean is the network's)."""

    def __init__(self, observation_space: gym.spaces.Space, action_space: gym.spaces.Space, lr_schedule: Any,
                 *, col_snapshot: PolicySnapshot, **kwargs: Any) -> None:
        self.col_snapshot = col_snapshot
        kwargs["ortho_init"] = False
        super().__init__(observation_space, action_space, lr_schedule, **kwargs)

    def _build_mlp_extractor(self) -> None:
        extractor = ActorAndCritic(self.col_snapshot)
        self.col_actor = extractor.actor
        self.mlp_extractor = extractor  # type: ignore[assignment]  # the slot's duck type

    def _build(self, lr_schedule: Any) -> None:
        super()._build(lr_schedule)
        self.action_net = nn.Identity()
        self.optimizer = self.optimizer_class(self.parameters(), lr=lr_schedule(1), **self.optimizer_kwargs)  # type: ignore[call-arg]

    def _get_constructor_parameters(self) -> dict[str, Any]:
        return {**super()._get_constructor_parameters(), "col_snapshot": self.col_snapshot}

    def actor_snapshot(self) -> PolicySnapshot:
        """The actor now, as a CoL policy (for checkpoints and ``col eval``)."""
        return self.col_actor.net.snapshot()


# ====================================================================== the behaviour-cloning term
class BehaviourCloning:
    """Adds ``w_k * grad MSE(actor(obs), action)`` on a dataset minibatch before each optimiser step."""

    def __init__(self, model: PPO, obs: np.ndarray, env_actions: np.ndarray, settings: FinetuneSettings) -> None:
        if len(obs) == 0:
            raise ConfigError("the human dataset is empty: nothing to clone; pass --bc-weight 0 to fine-tune on the reward alone")
        self.model = model
        self.obs = torch.as_tensor(obs, dtype=torch.float32)
        self.actions = torch.as_tensor(env_actions, dtype=torch.float32)
        self.settings = settings
        self.generator = torch.Generator().manual_seed(settings.seed)
        self.last_loss = float("nan")

    def weight(self) -> float:
        """The term's weight after the PPO updates done so far."""
        updates = self.model._n_updates // self.settings.n_epochs
        return self.settings.bc_weight * 0.5 ** (updates / self.settings.bc_half_life)

    def __call__(self, optimizer: torch.optim.Optimizer, args: Any, kwargs: Any) -> None:
        w = self.weight()
        if w <= 0.0:
            return
        idx = torch.randint(len(self.obs), (self.settings.bc_batch_size,), generator=self.generator)
        policy = self.model.policy
        assert isinstance(policy, CoLPolicy)
        loss = torch.mean((policy.col_actor(self.obs[idx]) - self.actions[idx]) ** 2)
        (w * loss).backward()
        self.last_loss = float(loss.detach())


def human_dataset(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """The person's observations and actions, the actions in the env's axis order; episodes the
    pilot discarded (the dataset's audit file) are left out, as the learner leaves them out."""
    rows = load_csv(path)
    keep = ~np.isin(rows.episode, sorted(discarded_episodes(path)))
    return (rows.obs[keep].astype(np.float32),
            rows.actions[keep][:, list(ENV_FROM_POLICY)].astype(np.float32))


def make_finetune_model(env: LandingEnv | VecEnv, snapshot: PolicySnapshot, settings: FinetuneSettings) -> PPO:
    """A seeded PPO whose actor is the checkpoint's network."""
    return PPO(CoLPolicy, env, n_steps=settings.n_steps, batch_size=settings.batch_size, n_epochs=settings.n_epochs,
               learning_rate=settings.learning_rate, gamma=settings.gamma, ent_coef=settings.ent_coef,
               policy_kwargs={"col_snapshot": snapshot, "log_std_init": settings.log_std_init},
               seed=settings.seed, device="cpu", verbose=0)


def dataset_beside(checkpoint: Path) -> Path:
    """A run folder's dataset for one of its checkpoints (``RUN/checkpoints/episode_NNN.npz``)."""
    return checkpoint.parent.parent / "human.csv"


# ====================================================================== the run
def run_finetune(checkpoint: Path, settings: FinetuneSettings, out_dir: Path, cfg: CompanionConfig | None = None,
                 config_path: Path | None = None, dataset: Path | None = None,
                 on_episode: EpisodeHook | None = None) -> dict[str, Any]:
    """Evaluate the checkpoint, fine-tune it, evaluate again; ``results.json`` and ``finetuned.npz``
    (a CoL checkpoint ``col eval`` flies) in ``out_dir``. A finished folder is returned as is; an
    interrupted one continues from its last PPO update; either only with the settings, checkpoint
    and dataset it was started with (others are refused before anything else)."""
    cfg = cfg or CompanionConfig()
    out_dir.mkdir(parents=True, exist_ok=True)
    data_path = dataset or dataset_beside(checkpoint)
    recorded = _check_same(out_dir, settings, checkpoint, data_path)
    if (out_dir / "results.json").exists():
        return dict(json.loads((out_dir / "results.json").read_text()))
    snapshot, meta = load_checkpoint(checkpoint)
    if settings.bc_weight > 0 and not data_path.is_file():
        raise ConfigError(f"no human dataset at {data_path} for the behaviour-cloning term; pass --dataset "
                          "or --bc-weight 0")
    obs, actions = human_dataset(data_path) if settings.bc_weight > 0 else (np.zeros((0, 15)), np.zeros((0, 4)))
    task = task_summary(record_run_config(out_dir, cfg, config_path))
    if not recorded:  # the inputs are good: the folder now belongs to this run
        (out_dir / "settings.json").write_text(json.dumps(_settings_of(settings, checkpoint, data_path)) + "\n")
    torch.set_num_threads(cfg.learner.torch_threads)
    before = _evaluated(out_dir / "before.json", snapshot, settings, cfg, config_path)
    venv = make_vec_env(4, cfg, settings.n_envs, config_path, inprocess=settings.inprocess)
    model, episodes, train_s = train_in_folder(
        venv, settings, out_dir, on_episode,
        make=lambda env: _with_bc(make_finetune_model(env, snapshot, settings), obs, actions, settings),
        on_load=lambda m: _with_bc(m, obs, actions, settings))
    policy = model.policy
    assert isinstance(policy, CoLPolicy)
    tuned = policy.actor_snapshot()
    save_checkpoint(out_dir / "finetuned.npz", tuned, LearnerConfig.model_validate(meta.config), dataset_size=len(obs),
                    episode=meta.episode, condition=f"{meta.condition}+ppo",
                    extra={"finetuned_from": str(checkpoint), "finetune": asdict(settings)})
    after = _evaluated(out_dir / "after.json", tuned, settings, cfg, config_path)
    results = {"settings": asdict(settings), "checkpoint": str(checkpoint), "dataset": str(data_path),
               "dataset_size": len(obs), "before": before,
               "train": {"episodes": len(episodes), "steps": sum(int(r["steps"]) for r in episodes),
                         "successes": sum(bool(r["success"]) for r in episodes), "wall_s": round(train_s, 1)},
               "after": after, "finetuned": str(out_dir / "finetuned.npz"), "task": task}
    (out_dir / "results.json").write_text(json.dumps(results, indent=1) + "\n")
    return results


def _with_bc(model: PPO, obs: np.ndarray, actions: np.ndarray, settings: FinetuneSettings) -> PPO:
    if settings.bc_weight > 0:
        model.policy.optimizer.register_step_pre_hook(BehaviourCloning(model, obs, actions, settings))
    return model


def _evaluated(path: Path, snapshot: PolicySnapshot, settings: FinetuneSettings, cfg: CompanionConfig,
               config_path: Path | None) -> dict[str, Any]:
    """The policy alone on the held-out starts (kept in ``path``: a resumed run does not redo it)."""
    if path.exists():
        return dict(json.loads(path.read_text()))
    env = LandingEnv(4, cfg, config_path=config_path, inprocess=settings.inprocess)
    try:
        report = evaluate(SnapshotActor(snapshot), env, settings.eval_episodes, settings.eval_seed)
    finally:
        env.close()
    path.write_text(json.dumps(report) + "\n")
    return report


class SnapshotActor:
    """A CoL policy with stable-baselines3's ``predict``, in the env's axis order."""

    def __init__(self, snapshot: PolicySnapshot) -> None:
        self.snapshot = snapshot

    def predict(self, observation: Any, *args: Any, **kwargs: Any) -> tuple[np.ndarray, None]:
        return self.snapshot.act(observation)[..., list(ENV_FROM_POLICY)], None


def _settings_of(settings: FinetuneSettings, checkpoint: Path, dataset: Path) -> dict[str, Any]:
    return {**asdict(settings), "checkpoint": str(checkpoint), "dataset": str(dataset)}


def _check_same(out_dir: Path, settings: FinetuneSettings, checkpoint: Path, dataset: Path) -> bool:
    """A folder continues, or reports, only the fine-tuning run it was started for; False for a
    folder no run has claimed yet."""
    now = _settings_of(settings, checkpoint, dataset)
    recorded = recorded_settings(out_dir)
    if recorded is None:
        return False
    if not (out_dir / "settings.json").exists():  # results.json keeps the paths beside its settings
        results = json.loads((out_dir / "results.json").read_text())
        recorded = {**recorded, "checkpoint": results.get("checkpoint"), "dataset": results.get("dataset")}
    refuse_other_settings(out_dir, {**asdict(FinetuneSettings()), **recorded}, now)  # added since: defaults
    return True
