"""The in-process env flies the same episodes as the MAVLink env: for the same seeds and actions,
the same observations, rewards, outcomes and touchdown points; and it passes Gymnasium's checker."""

from __future__ import annotations

import warnings
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from companion.config import CompanionConfig, load_companion_config
from companion.errors import ConfigError
from companion.rl.gym_env import LandingEnv
from companion.rl.vec_env import make_vec_env

PAPER = Path(__file__).resolve().parents[2] / "configs" / "paper.toml"
pytestmark = pytest.mark.e2e


def fly_recorded(env: LandingEnv, seed: int, actions: np.ndarray) -> dict:
    """One episode with the given actions (cycled); everything the agent and the truth saw."""
    obs, _ = env.reset(seed=seed)
    observations, rewards = [obs], []
    for k in range(env.max_steps):
        obs, reward, terminated, truncated, info = env.step(actions[k % len(actions)])
        observations.append(obs)
        rewards.append(reward)
        if terminated or truncated:
            break
    touchdown = env.ground_truth().get("touchdown")
    return {"obs": np.array(observations), "rewards": rewards, "info": info,
            "touchdown_ned": None if touchdown is None else np.array(touchdown["ned"])}


def assert_same_episode(a: dict, b: dict) -> None:
    assert a["info"] == b["info"]
    assert a["rewards"] == b["rewards"]
    assert a["obs"].shape == b["obs"].shape
    np.testing.assert_allclose(a["obs"], b["obs"], rtol=0, atol=1e-5)
    if a["touchdown_ned"] is None:
        assert b["touchdown_ned"] is None
    else:
        assert np.max(np.abs(a["touchdown_ned"] - b["touchdown_ned"])) < 1e-3  # within 1 mm


@pytest.mark.parametrize(("dims", "config"), [(2, None), (3, PAPER)], ids=["2-actions-default", "3-actions-paper"])
def test_inprocess_env_flies_the_same_episodes_as_the_mavlink_env(dims: int, config: Path | None) -> None:
    cfg = load_companion_config(config)
    rng = np.random.default_rng(11)
    actions = rng.uniform(-1, 1, (600, dims)).astype(np.float32)
    if dims == 3:
        actions[:, 2] = rng.uniform(-1.0, 0.2, 600)  # mostly down, so that some episodes touch down
    episodes = {}
    for inprocess in (False, True):
        env = LandingEnv(dims, cfg, config_path=config, inprocess=inprocess)
        try:
            episodes[inprocess] = [fly_recorded(env, seed, actions[seed:]) for seed in (0, 7)]
        finally:
            env.close()
    for over_mavlink, in_process in zip(episodes[False], episodes[True]):
        assert_same_episode(over_mavlink, in_process)
    assert any(e["touchdown_ned"] is not None for e in episodes[True]), "no touchdown compared"


@pytest.fixture(scope="module")
def fast_env() -> Iterator[LandingEnv]:
    env = LandingEnv(4, inprocess=True)
    yield env
    env.close()


def test_inprocess_env_passes_gymnasiums_env_checker(fast_env: LandingEnv) -> None:
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*infinity.*")  # telemetry is unbounded on purpose
        check_env(fast_env, skip_render_check=True)


def test_inprocess_env_refuses_an_external_connection() -> None:
    with pytest.raises(ConfigError, match="in-process"):
        LandingEnv(2, connection="udpin:127.0.0.1:14540", simulator="127.0.0.1:1", inprocess=True)


def test_vec_env_of_two_workers_steps_both_envs() -> None:
    venv = make_vec_env(2, CompanionConfig(), n_envs=2)
    try:
        venv.seed(5)
        obs = venv.reset()
        assert obs.shape == (2, 15)
        assert not np.array_equal(obs[0], obs[1])  # seeds 5 and 6: different starts
        for _ in range(3):
            obs, rewards, dones, infos = venv.step(np.zeros((2, 2), dtype=np.float32))
        assert obs.shape == (2, 15) and rewards.tolist() == [0.0, 0.0] and not dones.any()
        assert [i["seed"] for i in infos] == [5, 6]
    finally:
        venv.close()
    with pytest.raises(ConfigError, match="n_envs"):
        make_vec_env(2, CompanionConfig(), n_envs=0)
