"""Fine-tuning a CoL checkpoint with PPO: the actor PPO starts from flies exactly as the checkpoint
does, the behaviour-cloning term pulls towards the person's actions and decays, and a tiny run
in the SITL writes an evaluable, loadable result."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch

from companion.config import LearnerConfig
from companion.errors import ConfigError
from companion.learning.checkpoint import load_checkpoint, save_checkpoint
from companion.learning.dataset import HumanDataset
from companion.learning.policy import Normalisation, PolicyNet
from companion.msg.sample import Sample, Source
from companion.rl.finetune import (
    ENV_FROM_POLICY,
    BehaviourCloning,
    CoLPolicy,
    FinetuneSettings,
    SnapshotActor,
    human_dataset,
    make_finetune_model,
    run_finetune,
)
from companion.rl.gym_env import LandingEnv, observation_space

REPO = Path(__file__).resolve().parents[2]


class SpacesOnly(gym.Env[np.ndarray, np.ndarray]):
    """The landing env's spaces, for building a model without a SITL (never stepped)."""

    observation_space = observation_space()
    action_space = gym.spaces.Box(-1.0, 1.0, (4,), dtype=np.float32)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        return np.zeros(15, dtype=np.float32), {}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        raise AssertionError("not stepped")


def make_run(folder: Path, rng: np.random.Generator, samples: int = 40) -> Path:
    """A run folder as ``col fly`` leaves it: a checkpoint with its normalisation, and a dataset."""
    norm = Normalisation(rng.normal(0, 1, 15), rng.uniform(0.5, 3.0, 15))
    net = PolicyNet(normalisation=norm, init_std=0.3, generator=torch.Generator().manual_seed(1))
    (folder / "checkpoints").mkdir(parents=True)
    path = save_checkpoint(folder / "checkpoints" / "episode_003.npz", net, LearnerConfig(), dataset_size=samples,
                           episode=3, condition="col")
    with HumanDataset(folder / "human.csv") as data:
        for k in range(samples):
            data.append(Sample(0, k, 0.1 * k, Source.DEMONSTRATION, rng.normal(0, 2, 15), rng.uniform(-1, 1, 4)))
    return path


def test_actor_loaded_from_a_checkpoint_gives_the_checkpoints_actions(tmp_path: Path, rng: np.random.Generator) -> None:
    snap, _ = load_checkpoint(make_run(tmp_path, rng))
    model = make_finetune_model(SpacesOnly(), snap, FinetuneSettings())
    obs = rng.normal(0, 3, (200, 15)).astype(np.float32)
    actions, _ = model.predict(obs, deterministic=True)
    expected = snap.act(obs)[:, list(ENV_FROM_POLICY)]
    np.testing.assert_allclose(actions, expected, atol=1e-5)  # float32: torch vs NumPy rounding
    assert np.abs(expected).max() > 0.1  # the checkpoint does something, in both orders
    np.testing.assert_allclose(SnapshotActor(snap).predict(obs)[0], expected)
    policy = model.policy
    assert isinstance(policy, CoLPolicy)
    tuned = policy.actor_snapshot()  # the actor, back as a CoL policy, is the checkpoint
    for a, b in zip(tuned.weights, snap.weights, strict=True):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(tuned.normalisation.mean, snap.normalisation.mean)
    std = torch.exp(policy.log_std).detach().numpy()
    np.testing.assert_allclose(std, np.exp(-1.5), rtol=1e-6)  # the small initial action noise


def test_dataset_actions_come_in_the_envs_axis_order(tmp_path: Path, rng: np.random.Generator) -> None:
    make_run(tmp_path, rng)
    obs, actions = human_dataset(tmp_path / "human.csv")
    with HumanDataset(tmp_path / "human.csv") as data:
        raw = data.view()
        first = raw.actions[0]
    assert obs.shape == (40, 15) and actions.shape == (40, 4)
    roll, pitch, yaw, throttle = first
    np.testing.assert_allclose(actions[0], [pitch, roll, throttle, yaw])


def test_behaviour_cloning_term_pulls_towards_the_person_and_decays(tmp_path: Path, rng: np.random.Generator) -> None:
    snap, _ = load_checkpoint(make_run(tmp_path, rng))
    settings = FinetuneSettings(bc_weight=2.0, bc_half_life=4.0, learning_rate=1e-3)
    model = make_finetune_model(SpacesOnly(), snap, settings)
    obs, actions = human_dataset(tmp_path / "human.csv")
    bc = BehaviourCloning(model, obs, actions, settings)
    assert bc.weight() == 2.0
    model._n_updates = 4 * settings.n_epochs  # four PPO updates later: one half-life
    assert bc.weight() == pytest.approx(1.0)
    model._n_updates = 0
    optimiser = model.policy.optimizer
    optimiser.register_step_pre_hook(bc)
    policy = model.policy
    assert isinstance(policy, CoLPolicy)

    def mse() -> float:
        with torch.no_grad():
            return float(torch.mean((policy.col_actor(torch.as_tensor(obs)) - torch.as_tensor(actions)) ** 2))

    before = mse()
    for _ in range(100):  # optimiser steps with no PPO gradient: the term alone
        optimiser.zero_grad()
        optimiser.step()
    assert mse() < 0.8 * before
    with pytest.raises(ConfigError, match="empty"):
        BehaviourCloning(model, obs[:0], actions[:0], settings)


@pytest.mark.parametrize("bad", [{"action_dims": 2}, {"bc_weight": -1.0}, {"bc_half_life": 0.0}, {"episodes": 0},
                                 {"log_std_init": 3.0}])
def test_settings_refuse_nonsense(bad: dict) -> None:
    with pytest.raises(ConfigError):
        FinetuneSettings(**bad)


@pytest.mark.e2e
def test_a_tiny_finetuning_run_evaluates_before_and_after(tmp_path: Path, rng: np.random.Generator) -> None:
    checkpoint = make_run(tmp_path / "run", rng)
    settings = FinetuneSettings(episodes=2, eval_episodes=2, n_steps=64, batch_size=32, n_epochs=2)
    results = run_finetune(checkpoint, settings, tmp_path / "out")
    assert results["before"]["episodes"] == 2 and results["after"]["episodes"] == 2
    assert results["train"]["episodes"] == 2 and results["dataset_size"] == 40
    tuned, meta = load_checkpoint(tmp_path / "out" / "finetuned.npz")
    assert meta.condition == "col+ppo" and meta.extra["finetune"]["bc_weight"] == 1.0
    assert json.loads((tmp_path / "out" / "results.json").read_text()) == results
    snap, _ = load_checkpoint(checkpoint)
    assert any(not np.array_equal(a, b) for a, b in zip(tuned.weights, snap.weights, strict=True))  # it learned
    assert run_finetune(checkpoint, settings, tmp_path / "out") == results  # a finished folder is kept


@pytest.mark.e2e
def test_before_and_after_are_what_col_eval_measures(tmp_path: Path) -> None:
    """The env's evaluation of a CoL policy flies the same episodes as ``col eval`` over MAVLink
    (the committed CoL@4 policy on the calibrated task: touchdowns, one of them a success)."""
    from typer.testing import CliRunner

    from companion import cli
    from companion.config import load_companion_config
    from companion.rl.ppo import evaluate_runs

    checkpoint = REPO / "results" / "ppo" / "finetune" / "col4-P1" / "checkpoints" / "episode_003.npz"
    paper = REPO / "configs" / "paper.toml"
    result = CliRunner().invoke(cli.app, ["eval", str(checkpoint), "--episodes", "2", "--config", str(paper),
                                          "--run-dir", str(tmp_path / "eval")])
    assert result.exit_code == 0, result.output
    over_mavlink = [json.loads(line) for line in (tmp_path / "eval" / "episodes.jsonl").read_text().splitlines()]
    snap, _ = load_checkpoint(checkpoint)
    env = LandingEnv(4, load_companion_config(paper), config_path=paper, inprocess=True)
    try:
        in_env = evaluate_runs(SnapshotActor(snap), env, 2)
    finally:
        env.close()
    keys = ("seed", "steps", "outcome", "success")
    assert [[r[k] for k in keys] for r in over_mavlink] == [[r[k] for k in keys] for r in in_env]
    assert {r["outcome"] for r in in_env} == {"touchdown"} and any(r["success"] for r in in_env)
    for a, b in zip(over_mavlink, in_env, strict=True):
        assert abs(a["touchdown_distance_m"] - b["touchdown_distance_m"]) < 1e-3


def test_a_discarded_episode_is_not_cloned(tmp_path: Path, rng: np.random.Generator) -> None:
    """The pilot discarded episode 1 in the console: its rows stay in human.csv, but the
    behaviour-cloning term, like the learner, leaves them out."""
    make_run(tmp_path, rng)  # episode 0: 40 samples
    with HumanDataset(tmp_path / "human.csv") as data:
        for k in range(7):
            data.append(Sample(1, k, 0.1 * k, Source.DEMONSTRATION, rng.normal(0, 2, 15), rng.uniform(-1, 1, 4)))
        data.discard_episode(1, "nobody on the sticks")
    obs, actions = human_dataset(tmp_path / "human.csv")
    assert obs.shape == (40, 15) and actions.shape == (40, 4)
