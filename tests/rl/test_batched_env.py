"""The batched, session-free env flies the episodes of ``LandingEnv(inprocess=True)``: for the same
seeds and actions, step by step, the same observations (bit for bit), rewards, dones, infos (with
their terminal observations), reset infos and touchdown points; its stacked arithmetic gives what
the single env's gives one command at a time; bad actions fail or are repaired as there; batches
in worker processes step as one batch, and PPO trains the same in it."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.error import Error as GymnasiumError
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv

from companion.commands import CommandMapper, body_velocity
from companion.config import CommandsConfig, CompanionConfig, SafetyConfig, load_companion_config
from companion.control.safety import SetpointLimiter
from companion.errors import ColError, ConfigError
from companion.msg.command import JoystickCommand
from companion.msg.observation import Observation, normalised, pad_features, wrap_angle_rad
from companion.msg.pad import PadDetection
from companion.rl.batched_env import BatchedLandingEnv
from companion.rl.gym_env import LandingEnv, stick_rows, stick_values
from companion.rl.ppo import PpoSettings, run_ppo
from companion.rl.vec_env import make_vec_env

PAPER = Path(__file__).resolve().parents[2] / "configs" / "paper.toml"  # [sitl.disturbance] level = 0.2
Policy = Callable[[np.ndarray, int, np.random.Generator], np.ndarray]


class _EndTruth(gym.Wrapper[np.ndarray, np.ndarray, np.ndarray, np.ndarray]):
    """A LandingEnv that keeps the ground truth of its last finished episode, as the batched env
    does (a vec env resets at once)."""

    ended_truth: dict[str, Any] | None = None

    def step(self, action: np.ndarray) -> tuple[np.ndarray, Any, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        if terminated or truncated:
            self.ended_truth = self.env.unwrapped.ground_truth()  # type: ignore[attr-defined]
        return obs, reward, terminated, truncated, info


def _landing_envs(n: int, dims: int, cfg: CompanionConfig, config: Path | None) -> DummyVecEnv:
    return DummyVecEnv([lambda: _EndTruth(LandingEnv(dims, cfg, config_path=config, inprocess=True))
                        for _ in range(n)])


def _assert_same_step(a: tuple, b: tuple) -> None:
    """Two vec envs' step results: equal, observations and terminal observations bit for bit."""
    (obs_a, rew_a, done_a, infos_a), (obs_b, rew_b, done_b, infos_b) = a, b
    assert np.array_equal(obs_a, obs_b) and obs_a.dtype == obs_b.dtype == np.float32
    assert np.array_equal(rew_a, rew_b) and rew_a.dtype == rew_b.dtype
    assert np.array_equal(done_a, done_b)
    for info_a, info_b in zip(infos_a, infos_b, strict=True):
        assert set(info_a) == set(info_b)
        for key, value in info_a.items():
            if key == "terminal_observation":
                assert np.array_equal(value, info_b[key])
            else:
                assert value == info_b[key], key


def _assert_same_touchdowns(landing: VecEnv, batched: VecEnv, dones: np.ndarray) -> set[int]:
    """The touchdown points of the episodes that just ended, within 1 mm; the envs compared."""
    compared = set()
    for i in np.flatnonzero(dones).tolist():
        td_a = landing.get_attr("ended_truth", i)[0]["touchdown"]
        td_b = batched.get_attr("ended_truth", i)[0]["touchdown"]
        assert (td_a is None) == (td_b is None)
        if td_a is not None:
            assert np.max(np.abs(np.subtract(td_a["ned"], td_b["ned"]))) < 1e-3  # within 1 mm
            compared.add(i)
    return compared


def _fly_both(dims: int, cfg: CompanionConfig, config: Path | None, policy: Policy, seed: int,
              max_steps: int) -> list[dict[str, Any]]:
    """Two envs each way, seeded ``seed`` (env k: ``seed + k``), flown with ``policy`` of the
    observations until every env has finished an episode; the finished episodes' infos."""
    landing, batched = _landing_envs(2, dims, cfg, config), BatchedLandingEnv(2, dims, cfg, config_path=config)
    rng = np.random.default_rng(seed)
    ended: list[dict[str, Any]] = []
    try:
        landing.seed(seed)
        batched.seed(seed)
        obs = landing.reset()
        assert np.array_equal(obs, batched.reset()) and landing.reset_infos == batched.reset_infos
        finished = np.zeros(2, dtype=bool)
        for step in range(max_steps):
            actions = policy(obs, step, rng)
            result = landing.step(actions)
            _assert_same_step(result, batched.step(actions))
            assert landing.reset_infos == batched.reset_infos
            obs, dones = result[0], result[2]
            compared = _assert_same_touchdowns(landing, batched, dones)
            ended += [{**result[3][i], "touchdown_compared": i in compared} for i in np.flatnonzero(dones).tolist()]
            finished |= dones
            if finished.all():
                return ended
    finally:
        landing.close()
        batched.close()
    raise AssertionError(f"not every env finished an episode within {max_steps} steps")


def _towards_the_pad_or_random(obs: np.ndarray, step: int, rng: np.random.Generator) -> np.ndarray:
    """Env 0 steers towards the pad it sees (a P controller: lands on it); env 1 flies random
    sticks with a bad value now and then (NaN, out of range: repaired by each env's mapper)."""
    u, v, seen = obs[0, 12], obs[0, 13], obs[0, 14] > 0
    steer = np.clip([-2.0 * v, 2.0 * u], -1, 1) if seen else np.zeros(2)
    noise = rng.uniform(-1, 1, 2)
    if step % 17 == 5:
        noise[step % 2] = np.nan
    elif step % 17 == 11:
        noise[step % 2] = 5.0
    return np.array([steer, noise], dtype=np.float32)


def _away_or_hover(obs: np.ndarray, step: int, rng: np.random.Generator) -> np.ndarray:
    """Env 0 flies forward and turns, climbing (out of a small geofence); env 1 hovers with small
    random sticks (a timeout)."""
    away = [1.0, 0.3, 0.5, 0.4]
    hover = [*rng.uniform(-0.2, 0.2, 2), rng.uniform(-0.1, 0.1), rng.uniform(-0.3, 0.3)]
    return np.array([away, hover], dtype=np.float32)


def test_same_episodes_as_the_inprocess_env_at_the_experiments_disturbance() -> None:
    """Level 0.2 (configs/paper.toml), 2 actions: a landing on the pad and a touchdown off it."""
    ended = _fly_both(2, load_companion_config(PAPER), PAPER, _towards_the_pad_or_random, seed=3, max_steps=400)
    outcomes = {(info["outcome"], info["success"]) for info in ended}
    assert ("touchdown", True) in outcomes and ("touchdown", False) in outcomes, ended
    assert all(info["touchdown_compared"] for info in ended)


def test_same_episodes_without_disturbance_with_expo_and_rate_limits() -> None:
    """Level 0 (the SITL's defaults), 4 actions, expo and acceleration limits on: a geofence
    exit and a timeout."""
    cfg = CompanionConfig()
    cfg = cfg.model_copy(update={
        "commands": cfg.commands.model_copy(update={"expo": 0.3, "deadband": 0.1}),
        "safety": cfg.safety.model_copy(update={"fence_radius_m": 8.0, "max_accel_xy_m_s2": 3.0,
                                                "max_accel_z_m_s2": 2.0, "max_yaw_accel_rad_s2": 1.5}),
        "session": cfg.session.model_copy(update={"max_steps": 90}),
    })
    ended = _fly_both(4, cfg, None, _away_or_hover, seed=10, max_steps=200)
    assert {info["outcome"] for info in ended} >= {"fence", "timeout"}, ended
    assert all(not info["TimeLimit.truncated"] for info in ended if info["outcome"] == "fence")
    assert all(info["TimeLimit.truncated"] for info in ended if info["outcome"] == "timeout")


# ----- the stacked arithmetic is the single env's, row by row ------------------------------
def test_stacked_sticks_commands_and_limits_are_each_commands_own(rng: np.random.Generator) -> None:
    commands = CommandsConfig(expo=0.4, deadband=0.07)
    safety = SafetyConfig(max_accel_xy_m_s2=2.0, max_accel_z_m_s2=1.0, max_yaw_accel_rad_s2=0.5)
    mapper, alone, stacked = CommandMapper(commands), SetpointLimiter(commands, safety), SetpointLimiter(commands, safety)
    last = None
    for dims in (2, 3, 4):
        actions = rng.uniform(-1, 1, (50, dims))
        actions[::7] = 0.0
        sticks = stick_rows(actions, -0.5)
        assert np.array_equal(sticks, np.array([stick_values(a, dims, -0.5) for a in actions]))
        rows = body_velocity(mapper.physical(sticks)[0])
        one = [alone.apply(mapper.to_setpoint(JoystickCommand.from_array(s)), 0.1).as_tuple() for s in sticks]
        out = stacked.clipped(rows)
        for k in range(len(out)):  # one env, step after step: each row limited by the one before
            previous = out[k - 1] if k else last
            if previous is not None:
                out[k] = stacked.rate_limited(out[k][None], previous[None], 0.1)[0]
        last = out[-1]
        assert np.array_equal(out, np.array(one))


def test_stacked_observation_vectors_are_each_observations_own(rng: np.random.Generator) -> None:
    n = 40
    telemetry = rng.normal(0, 3, (n, 12))
    pads = [PadDetection(*rng.uniform(-50, 400, 2), rng.uniform(0.5, 300), False) for _ in range(n)]
    u, v, r = (np.array([getattr(p, f) for p in pads]) for f in ("u_px", "v_px", "radius_px"))
    raw = telemetry.copy()
    raw[:, 5] = [wrap_angle_rad(y) for y in telemetry[:, 5]]
    stacked = normalised(raw, np.column_stack(pad_features(u, v, r, (320, 240))))
    alone = [Observation(tuple(t[0:3]), tuple(t[3:6]), tuple(t[6:9]), tuple(t[9:12]), p, (320, 240), 0).to_vector()
             for t, p in zip(telemetry, pads, strict=True)]
    assert np.array_equal(stacked, np.array(alone))


# ----- bad input ---------------------------------------------------------------------------
@pytest.fixture(scope="module")
def batched() -> Any:
    env = BatchedLandingEnv(2, 2)
    yield env
    env.close()


def test_actions_of_the_wrong_shape_are_refused_with_the_shape_wanted(batched: BatchedLandingEnv) -> None:
    batched.reset()
    for bad in (np.zeros((2, 3)), np.zeros((3, 2)), np.zeros(2), np.float32(0.0)):
        with pytest.raises(ValueError, match=r"shape \(2, 2\)"):
            batched.step(bad)
    obs, *_ = batched.step(np.zeros((2, 2)))  # still usable after a refused action
    assert obs.shape == (2, 15)


def test_non_finite_actions_are_repaired_and_counted_per_env(batched: BatchedLandingEnv) -> None:
    batched.reset()
    before = [lane.mapper.counts.non_finite_axes for lane in batched.lanes]
    obs, *_ = batched.step(np.array([[np.nan, np.inf], [0.1, 0.2]], dtype=np.float32))
    assert np.isfinite(obs).all()
    after = [lane.mapper.counts.non_finite_axes for lane in batched.lanes]
    assert [a - b for a, b in zip(after, before, strict=True)] == [2, 0]


def test_bad_settings_and_seeds_fail_as_in_the_single_env() -> None:
    with pytest.raises(ConfigError, match="action_dims"):
        BatchedLandingEnv(1, 5)
    with pytest.raises(ConfigError, match="descent_throttle"):
        BatchedLandingEnv(1, 2, descent_throttle=0.5)
    with pytest.raises(ConfigError, match="n_envs"):
        BatchedLandingEnv(0)
    with pytest.raises(ConfigError, match="MAVLink"):
        make_vec_env(2, CompanionConfig(), 2, inprocess=False, batched=True)
    env = BatchedLandingEnv(1)
    try:
        env.seed(-1)
        with pytest.raises(GymnasiumError):
            env.reset()
    finally:
        env.close()
    with pytest.raises(ColError, match="closed"):
        env.step(np.zeros((1, 2)))


def test_attributes_and_methods_are_each_envs_own(batched: BatchedLandingEnv) -> None:
    batched.seed(40)
    batched.reset()
    assert batched.get_attr("max_steps") == [500, 500]
    assert [lane.seed for lane in batched.lanes] == [40, 41]
    truths = batched.env_method("ground_truth", indices=[1])
    assert len(truths) == 1 and truths[0]["episode"] >= 2 and truths[0]["touchdown"] is None
    assert batched.env_is_wrapped(gym.Wrapper) == [False, False]


# ----- in worker processes ---------------------------------------------------------------------
@pytest.mark.e2e
def test_batches_in_two_workers_step_as_one_batch_in_this_process() -> None:
    cfg = load_companion_config(PAPER)
    workers = make_vec_env(2, cfg, 3, PAPER, batched=True, workers=2)
    alone = make_vec_env(2, cfg, 3, PAPER, batched=True)
    rng = np.random.default_rng(1)
    try:
        for venv in (workers, alone):
            venv.seed(20)
        assert np.array_equal(workers.reset(), alone.reset())
        for _ in range(30):
            actions = rng.uniform(-1, 1, (3, 2)).astype(np.float32)
            _assert_same_step(workers.step(actions), alone.step(actions))
        assert workers.get_attr("seed") == alone.get_attr("seed") == [20, 21, 22]
    finally:
        workers.close()
        alone.close()


@pytest.mark.e2e
def test_ppo_trains_the_same_in_the_batched_env(tmp_path: Path) -> None:
    """The same training episodes (PPO updating between them) and the same evaluation."""
    settings = PpoSettings(episodes=3, eval_episodes=1, n_steps=64, batch_size=32, n_epochs=2)
    cfg = load_companion_config(PAPER)
    runs = {}
    for batched in (False, True):
        results = run_ppo(settings, tmp_path / str(batched), cfg, PAPER, batched=batched)
        lines = (tmp_path / str(batched) / "train_episodes.jsonl").read_text().splitlines()
        episodes = [{k: v for k, v in json.loads(line).items() if k != "wall_s"} for line in lines]
        runs[batched] = (episodes, results["eval"]["successes"], results["eval"]["touchdown_distance_m_median"])
    assert runs[True] == runs[False] and len(runs[True][0]) == 3
