"""The PPO baseline: settings checks, summaries, and a tiny real training run in the SITL."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from stable_baselines3 import PPO

from companion.config import CompanionConfig
from companion.errors import ConfigError
from companion.rl.ppo import EVAL_SEED, PpoSettings, learning_curve, make_model, run_ppo, summarise
from companion.rl.vec_env import make_vec_env

TINY = {"episodes": 2, "eval_episodes": 2, "n_steps": 64, "batch_size": 32, "n_epochs": 2}


def run(n: int, success: bool, outcome: str = "touchdown", distance: float | None = 1.0) -> dict:
    return {"episode": n, "seed": n, "steps": 100, "outcome": outcome, "success": success,
            "touchdown_distance_m": distance}


@pytest.mark.parametrize("bad", [{"action_dims": 1}, {"episodes": 0}, {"n_steps": 1}, {"learning_rate": 0.0},
                                 {"gamma": 1.5}, {"seed": -1}])
def test_settings_refuse_nonsense(bad: dict) -> None:
    with pytest.raises(ConfigError):
        PpoSettings(**bad)


def test_summary_counts_successes_with_an_interval() -> None:
    runs = [run(0, True, distance=0.2), run(1, False, distance=2.0), run(2, False, "timeout", None),
            run(3, False, "fence", None)]
    s = summarise(runs)
    assert (s["episodes"], s["successes"], s["touchdowns"], s["timeouts"], s["fence"]) == (4, 1, 2, 1, 1)
    assert s["success_rate"] == 0.25 and s["ci95"][0] < 0.25 < s["ci95"][1]
    assert s["touchdown_distance_m_median"] == pytest.approx(1.1)


def test_learning_curve_is_success_rate_per_block() -> None:
    episodes = [run(i, i >= 10) for i in range(20)]
    curve = learning_curve(episodes, blocks=4)
    assert [b["first_episode"] for b in curve] == [0, 5, 10, 15]
    assert [b["success_rate"] for b in curve] == [0.0, 0.0, 1.0, 1.0]


@pytest.mark.e2e
def test_a_tiny_training_run_writes_an_evaluable_model(tmp_path: Path) -> None:
    results = run_ppo(PpoSettings(**TINY), tmp_path)
    assert results["train"]["episodes"] == 2 and results["train"]["steps"] > 100  # more than one rollout of 64
    lines = [json.loads(line) for line in (tmp_path / "train_episodes.jsonl").read_text().splitlines()]
    assert [r["seed"] for r in lines] == [0, 1]  # training starts: seed + i
    assert all(r["outcome"] in ("touchdown", "fence", "timeout") for r in lines)
    assert results["eval"]["episodes"] == 2 and results["eval"]["seed0"] == EVAL_SEED
    assert json.loads((tmp_path / "results.json").read_text()) == results
    assert results["task"] == {"config_path": None, "disturbance_level": 0.0}  # the task it trained on
    assert json.loads((tmp_path / "run_config.json").read_text())["sitl"]["disturbance"]["level"] == 0.0
    model = PPO.load(tmp_path / "model.zip", device="cpu")
    action, _ = model.predict(np.zeros(15, dtype=np.float32), deterministic=True)
    assert action.shape == (2,) and np.all(np.abs(action) <= 1.0)


def _records(folder: Path) -> list[dict]:
    lines = (folder / "train_episodes.jsonl").read_text().splitlines()
    return [{k: v for k, v in json.loads(line).items() if k != "wall_s"} for line in lines]


@pytest.mark.slow
def test_training_repeats_exactly_for_a_seed(tmp_path: Path) -> None:
    first = run_ppo(PpoSettings(**TINY, seed=3), tmp_path / "a")
    second = run_ppo(PpoSettings(**TINY, seed=3), tmp_path / "b")
    assert [r["seed"] for r in _records(tmp_path / "a")] == [3, 4]
    assert _records(tmp_path / "a") == _records(tmp_path / "b")
    first["eval"].pop("wall_s")
    second["eval"].pop("wall_s")
    assert first["eval"] == second["eval"]


@pytest.mark.e2e
def test_envs_grouped_in_one_worker_train_the_same_run_as_one_worker_per_env(tmp_path: Path) -> None:
    settings = PpoSettings(**{**TINY, "n_envs": 2, "eval_episodes": 1})
    grouped = run_ppo(settings, tmp_path / "grouped", workers=1)
    apart = run_ppo(settings, tmp_path / "apart")
    assert _records(tmp_path / "grouped") == _records(tmp_path / "apart")
    assert len(_records(tmp_path / "grouped")) >= 2
    grouped["eval"].pop("wall_s")
    apart["eval"].pop("wall_s")
    assert grouped["eval"] == apart["eval"]
    with pytest.raises(ConfigError, match="workers"):
        make_vec_env(2, CompanionConfig(), n_envs=2, workers=3)


class Interrupt(Exception):
    """Stands in for Ctrl-C in the middle of training."""


@pytest.mark.e2e
def test_an_interrupted_run_continues_from_its_folder(tmp_path: Path) -> None:
    settings = PpoSettings(**{**TINY, "episodes": 4}, log_std_init=-1.0, ent_coef=0.01)

    def stop_after_two(record: dict) -> None:
        if record["episode"] == 2:
            raise Interrupt

    with pytest.raises(Interrupt):
        run_ppo(settings, tmp_path, on_episode=stop_after_two)
    saved = json.loads((tmp_path / "checkpoint.json").read_text())["episodes"]
    assert 1 <= saved <= 2 and not (tmp_path / "results.json").exists()
    results = run_ppo(settings, tmp_path)
    records = _records(tmp_path)
    assert [r["episode"] for r in records] == [0, 1, 2, 3]
    assert [r["seed"] for r in records] == [0, 1, 2, 3]  # training starts go on at seed + episodes done
    assert results["train"]["episodes"] == 4 and results["settings"]["log_std_init"] == -1.0
    assert run_ppo(settings, tmp_path) == results  # a finished folder is not run again
    (tmp_path / "results.json").unlink()
    with pytest.raises(ConfigError, match="other settings"):
        run_ppo(PpoSettings(**{**TINY, "episodes": 5}), tmp_path)


def test_initial_log_std_and_entropy_bonus_reach_the_model() -> None:
    venv = make_vec_env(2, CompanionConfig())
    try:
        model = make_model(venv, PpoSettings(**TINY, log_std_init=-1.5, ent_coef=0.02))
        assert model.ent_coef == 0.02
        np.testing.assert_allclose(model.policy.log_std.detach().numpy(), [-1.5, -1.5])
    finally:
        venv.close()


@pytest.mark.e2e
def test_an_unfinished_runs_checkpoint_is_evaluated_on_held_out_starts(tmp_path: Path) -> None:
    from companion.rl.ppo import evaluate_checkpoint

    with pytest.raises(ConfigError, match="no PPO checkpoint"):
        evaluate_checkpoint(tmp_path)

    def stop_after_one(record: dict) -> None:
        if record["episode"] == 1:
            raise Interrupt

    with pytest.raises(Interrupt):
        run_ppo(PpoSettings(**{**TINY, "episodes": 4}), tmp_path, on_episode=stop_after_one)
    result = evaluate_checkpoint(tmp_path, episodes=1)
    assert result["train_episodes_seen"] >= 1 and result["eval"]["episodes"] == 1
    assert json.loads((tmp_path / "checkpoint_eval.json").read_text()) == result
