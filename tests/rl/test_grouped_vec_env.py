"""Envs grouped in few worker processes behave as the same envs stepped in one process: the same
observations, rewards, dones and infos (auto-reset and ``terminal_observation`` included), the
attributes of the right envs, and a worker's error raised in the parent."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from stable_baselines3.common.vec_env import DummyVecEnv

from companion.config import load_companion_config
from companion.errors import ConfigError
from companion.rl.grouped_vec_env import GroupedSubprocVecEnv
from companion.rl.vec_env import env_factory, make_vec_env

PAPER = Path(__file__).resolve().parents[2] / "configs" / "paper.toml"
pytestmark = pytest.mark.e2e


def _factories(n: int) -> list:
    return [env_factory(2, load_companion_config(PAPER), PAPER) for _ in range(n)]


def _roll(venv, steps: int) -> list:  # noqa: ANN001 - any VecEnv
    """Seeds 7.., then steps with actions that differ per env and step, until an env is done."""
    rng = np.random.default_rng(3)
    venv.seed(7)
    record = [venv.reset()]
    for _ in range(steps):
        obs, rewards, dones, infos = venv.step(rng.uniform(-1, 1, (venv.num_envs, 2)).astype(np.float32))
        record.append((obs, rewards, dones, infos))
        if dones.any():
            break
    return record


def test_grouped_envs_step_as_the_same_envs_in_one_process() -> None:
    grouped = make_vec_env(2, load_companion_config(PAPER), n_envs=3, config_path=PAPER, workers=2)
    assert isinstance(grouped, GroupedSubprocVecEnv)
    try:
        got = _roll(grouped, 400)
        assert grouped.get_attr("action_dims", indices=[2]) == [2]
        truths = grouped.env_method("ground_truth", indices=[0, 2])
        assert len(truths) == 2 and all(isinstance(t, dict) for t in truths)
    finally:
        grouped.close()
    single = DummyVecEnv(_factories(3))
    try:
        want = _roll(single, 400)
    finally:
        single.close()
    assert len(got) == len(want) > 2
    np.testing.assert_array_equal(got[0], want[0])
    for (o1, r1, d1, i1), (o2, r2, d2, i2) in zip(got[1:], want[1:], strict=True):
        np.testing.assert_array_equal(o1, o2)
        np.testing.assert_array_equal(r1, r2)
        np.testing.assert_array_equal(d1, d2)
        for a, b in zip(i1, i2, strict=True):
            assert a.keys() == b.keys()
            if "terminal_observation" in a:
                np.testing.assert_array_equal(a.pop("terminal_observation"), b.pop("terminal_observation"))
            assert a == b
    assert got[-1][2].any()  # an episode ended: the auto-reset path was compared too


def test_a_workers_error_is_raised_in_the_parent_and_the_env_still_closes() -> None:
    venv = GroupedSubprocVecEnv(_factories(2), n_workers=2)
    try:
        with pytest.raises(AttributeError, match="no_such_method"):
            venv.env_method("no_such_method", indices=[1])
        assert venv.get_attr("action_dims") == [2, 2]  # the worker answers on
    finally:
        venv.close()
    assert not any(p.is_alive() for p in venv.processes)


def test_bad_worker_counts_are_refused() -> None:
    with pytest.raises(ConfigError, match="n_workers"):
        GroupedSubprocVecEnv(_factories(2), n_workers=3)
    with pytest.raises(ConfigError, match="at least one env"):
        GroupedSubprocVecEnv([], n_workers=1)


def _broken_env():  # noqa: ANN202 - a factory that fails as a bad config would
    raise ConfigError("this env cannot be built")


def test_a_worker_that_cannot_build_its_envs_stops_them_all_with_its_error() -> None:
    with pytest.raises(ConfigError, match="cannot be built"):
        GroupedSubprocVecEnv([*_factories(1), _broken_env], n_workers=2)


def test_envs_are_split_in_groups_that_differ_by_at_most_one() -> None:
    venv = GroupedSubprocVecEnv([_factories(1)[0]] * 5, n_workers=3)
    try:
        assert [(p.start, p.stop) for p in venv._slices] == [(0, 2), (2, 4), (4, 5)]
        assert len(venv.processes) == 3 and venv.get_attr("action_dims") == [2] * 5
    finally:
        venv.close()
