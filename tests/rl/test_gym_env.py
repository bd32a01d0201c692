"""LandingEnv against the real lockstep SITL: Gymnasium's checker, the reset/step contract,
the sparse reward (1 only for a touchdown the ground truth calls a success) and the step cap."""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterator

import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from companion.config import CompanionConfig
from companion.errors import ColError, ConfigError, LinkLost
from companion.msg.observation import OBS_DIM
from companion.rl.gym_env import DESCENT_THROTTLE, LandingEnv, stick_values

# Indices in the observation vector (companion/msg/observation.py).
DOWN, YAW, VD, YAW_RATE = 2, 5, 8, 11


@pytest.fixture(scope="module")
def env2() -> Iterator[LandingEnv]:
    env = LandingEnv(2)
    yield env
    env.close()


@pytest.fixture(scope="module")
def env4_short() -> Iterator[LandingEnv]:
    """All four axes, episodes capped at 5 steps through the config."""
    cfg = CompanionConfig()
    cfg = cfg.model_copy(update={"session": cfg.session.model_copy(update={"max_steps": 5})})
    env = LandingEnv(4, cfg)
    yield env
    env.close()


def steer_to_pad(env: LandingEnv, obs: np.ndarray) -> np.ndarray:
    """A test-only pilot that cheats with the ground truth: (pitch, roll) towards the pad."""
    truth = env.ground_truth()
    dn, de = np.asarray(truth["pad_ned"][:2]) - np.asarray(truth["vehicle_ned"][:2])
    yaw = float(obs[YAW]) * math.pi
    forward = math.cos(yaw) * dn + math.sin(yaw) * de
    right = -math.sin(yaw) * dn + math.cos(yaw) * de
    return np.clip(np.array([forward, right]) * 0.5, -0.6, 0.6).astype(np.float32)


def fly(env: LandingEnv, seed: int, pilot) -> tuple[list[float], bool, bool, dict]:  # type: ignore[no-untyped-def]
    obs, _ = env.reset(seed=seed)
    rewards: list[float] = []
    while True:
        obs, reward, terminated, truncated, info = env.step(pilot(env, obs))
        rewards.append(reward)
        if terminated or truncated:
            return rewards, terminated, truncated, info


# ----- pure parts --------------------------------------------------------------------------------
def test_stick_values_map_each_action_subset_to_the_four_sticks() -> None:
    roll, pitch, yaw, throttle = stick_values(np.array([0.5, -0.25]), 2, DESCENT_THROTTLE)
    assert (roll, pitch, yaw, throttle) == (-0.25, 0.5, 0.0, DESCENT_THROTTLE)
    assert stick_values(np.array([0.5, -0.25, 0.75]), 3, -0.5).tolist() == [-0.25, 0.5, 0.0, 0.75]
    assert stick_values(np.array([0.5, -0.25, 0.75, -1.0]), 4, -0.5).tolist() == [-0.25, 0.5, -1.0, 0.75]
    with pytest.raises(ValueError, match="3 values"):
        stick_values(np.zeros(2), 3, -0.5)


def test_bad_settings_are_refused_before_starting_anything() -> None:
    with pytest.raises(ConfigError, match="action_dims"):
        LandingEnv(5)
    with pytest.raises(ConfigError, match="descent_throttle"):
        LandingEnv(2, descent_throttle=0.5)
    with pytest.raises(ConfigError, match="--simulator"):
        LandingEnv(2, connection="udpin:127.0.0.1:14540")


# ----- against the SITL --------------------------------------------------------------------------
e2e = pytest.mark.e2e


@e2e
@pytest.mark.parametrize("which", ["env2", "env4_short"])
def test_passes_gymnasiums_env_checker(which: str, request: pytest.FixtureRequest) -> None:
    env = request.getfixturevalue(which)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*infinity.*")  # telemetry is unbounded on purpose
        check_env(env, skip_render_check=True)


@e2e
def test_reset_and_step_contract(env2: LandingEnv) -> None:
    assert env2.action_space.shape == (2,) and env2.observation_space.shape == (OBS_DIM,)
    obs, info = env2.reset(seed=42)
    assert obs.dtype == np.float32 and obs.shape == (OBS_DIM,) and obs in env2.observation_space
    assert info == {"seed": 42}
    assert obs[DOWN] < -0.5, "the episode starts high above the ground"
    first, reward, terminated, truncated, info = env2.step(np.zeros(2, dtype=np.float32))
    assert first.dtype == np.float32 and reward == 0.0 and not terminated and not truncated
    assert info["steps"] == 1 and info["outcome"] is None and info["success"] is False
    again, _ = env2.reset(seed=42)
    np.testing.assert_array_equal(again, obs)  # the same start, exactly (lockstep)
    _, info = env2.reset()
    assert info == {"seed": 43}  # without a seed: the next start


@e2e
def test_constant_descent_in_the_two_action_task(env2: LandingEnv) -> None:
    env2.reset(seed=5)
    for _ in range(15):
        obs, *_ = env2.step(np.zeros(2, dtype=np.float32))
    assert obs[VD] * 5.0 > 0.3, f"descending at {obs[VD] * 5.0:.2f} m/s with the throttle held at {DESCENT_THROTTLE}"


@e2e
def test_reward_is_one_only_on_a_successful_touchdown(env2: LandingEnv) -> None:
    rewards, terminated, truncated, info = fly(env2, 3, steer_to_pad)
    assert terminated and not truncated and info["outcome"] == "touchdown"
    assert info["success"] is True and info["touchdown_distance_m"] < 0.5
    assert rewards[-1] == 1.0 and sum(rewards) == 1.0

    rewards, terminated, _, info = fly(env2, 9, lambda env, obs: np.zeros(2, dtype=np.float32))
    assert terminated and info["outcome"] == "touchdown", "held sticks still land, off the pad"
    assert info["success"] is False and info["touchdown_distance_m"] > 0.5
    assert sum(rewards) == 0.0


@e2e
def test_episode_cap_from_the_config(env4_short: LandingEnv) -> None:
    rewards, terminated, truncated, info = fly(env4_short, 1, lambda env, obs: np.zeros(4, dtype=np.float32))
    assert len(rewards) == 5 and truncated and not terminated
    assert info["outcome"] == "timeout" and sum(rewards) == 0.0
    with pytest.raises(ColError, match="reset"):
        env4_short.step(np.zeros(4, dtype=np.float32))


@e2e
def test_throttle_and_yaw_are_controlled_with_four_actions(env4_short: LandingEnv) -> None:
    env4_short.reset(seed=2)
    for _ in range(4):
        obs, *_ = env4_short.step(np.array([0.0, 0.0, 1.0, 1.0], dtype=np.float32))
    assert obs[VD] < 0.0, "throttle +1 climbs"
    assert obs[YAW_RATE] > 0.0, "yaw +1 turns clockwise"


@e2e
def test_a_missed_frame_truncates_the_episode_without_reward(env2: LandingEnv, monkeypatch: pytest.MonkeyPatch) -> None:
    obs, _ = env2.reset(seed=4)

    def no_frame() -> None:
        raise LinkLost("no frame from the SITL in time")

    monkeypatch.setattr(env2.lane, "next_frame", no_frame)  # the SITL sends no frame in time
    last, reward, terminated, truncated, info = env2.step(np.zeros(2, dtype=np.float32))
    assert truncated and not terminated and reward == 0.0 and info["outcome"] == "link_lost"
    np.testing.assert_array_equal(last, obs)
    monkeypatch.undo()
    again, _ = env2.reset(seed=4)  # the next episode starts normally
    np.testing.assert_array_equal(again, obs)

