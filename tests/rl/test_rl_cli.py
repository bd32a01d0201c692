"""``col ppo`` and ``col finetune`` as a person meets them: help, clear errors, the random policy."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from companion import cli
from tests.rl.test_finetune import make_run


@pytest.mark.parametrize("command", ["ppo", "finetune"])
def test_help_describes_the_command(command: str) -> None:
    result = CliRunner().invoke(cli.app, [command, "--help"])
    assert result.exit_code == 0 and "--episodes" in result.output and "--out" in result.output


def test_finetune_refuses_a_missing_checkpoint_or_dataset(tmp_path: Path, rng: np.random.Generator) -> None:
    result = CliRunner().invoke(cli.app, ["finetune", str(tmp_path / "none.npz"), "--out", str(tmp_path / "o")])
    assert result.exit_code == 2 and "does not exist" in result.output
    checkpoint = make_run(tmp_path / "run", rng)
    (tmp_path / "run" / "human.csv").unlink()
    result = CliRunner().invoke(cli.app, ["finetune", str(checkpoint), "--out", str(tmp_path / "o")])
    assert result.exit_code == 2 and "no human dataset" in result.output and "--bc-weight 0" in result.output


@pytest.mark.e2e
def test_random_policy_is_measured_on_the_training_starts(tmp_path: Path) -> None:
    result = CliRunner().invoke(cli.app, ["ppo", "--random", "--actions", "2", "--episodes", "2", "--out", str(tmp_path)])
    assert result.exit_code == 0, result.output
    saved = json.loads((tmp_path / "random.json").read_text())
    assert saved["summary"]["episodes"] == 2 and [e["seed"] for e in saved["episodes"]] == [0, 1]
    assert json.loads(result.output.strip().splitlines()[-1]) == saved["summary"]


def finished_ppo_folder(folder: Path, **settings: object) -> dict:
    """A finished ``col ppo`` folder as the run leaves it (no training here): settings and results."""
    from dataclasses import asdict

    from companion.rl.ppo import PpoSettings

    recorded = asdict(PpoSettings(**settings))  # type: ignore[arg-type]
    results = {"settings": recorded, "train": {"episodes": 3, "wall_s": 1.0},
               "eval": {"episodes": 2, "successes": 1, "success_rate": 0.5, "ci95": [0.1, 0.9]}}
    folder.mkdir(parents=True)
    (folder / "settings.json").write_text(json.dumps(recorded) + "\n")
    (folder / "results.json").write_text(json.dumps(results) + "\n")
    return results


def test_ppo_on_a_finished_folder_refuses_other_options_first(tmp_path: Path) -> None:
    """It printed the old 2-action run's summary, rc 0, for --actions 4 --log-std-init -2."""
    out = tmp_path / "ppo2"
    finished_ppo_folder(out, action_dims=2, episodes=3, eval_episodes=2)
    before = (out / "results.json").read_bytes()
    other = CliRunner().invoke(cli.app, ["ppo", "--out", str(out), "--actions", "4", "--log-std-init", "-2",
                                         "--episodes", "3", "--eval-episodes", "2"])
    assert other.exit_code == 2, other.output
    assert "finished run with other settings" in other.output
    assert "action_dims: the run has 2, asked 4" in other.output and "log_std_init: the run has 0.0, asked -2.0" in other.output
    assert "trained" not in other.output  # no old summary presented as this run's
    same = CliRunner().invoke(cli.app, ["ppo", "--out", str(out), "--episodes", "3", "--eval-episodes", "2"])
    assert same.exit_code == 0 and "final policy 1/2" in same.output, same.output
    assert (out / "results.json").read_bytes() == before


def test_ppo_checks_a_finished_folder_without_settings_json_against_its_results(tmp_path: Path) -> None:
    from companion.errors import ConfigError
    from companion.rl.ppo import PpoSettings, run_ppo

    out = tmp_path / "old"
    finished_ppo_folder(out, action_dims=3, episodes=3, eval_episodes=2)
    (out / "settings.json").unlink()
    with pytest.raises(ConfigError, match="action_dims: the run has 3, asked 2"):
        run_ppo(PpoSettings(action_dims=2, episodes=3, eval_episodes=2), out)
    assert not (out / "settings.json").exists()  # nothing written for the refused run
    assert run_ppo(PpoSettings(action_dims=3, episodes=3, eval_episodes=2), out)["eval"]["successes"] == 1


def test_finetune_on_a_finished_folder_refuses_other_options_first(tmp_path: Path) -> None:
    from dataclasses import asdict

    from companion.rl.finetune import FinetuneSettings

    out, checkpoint = tmp_path / "ft", tmp_path / "run" / "checkpoints" / "episode_003.npz"
    recorded = {**asdict(FinetuneSettings(episodes=3)), "checkpoint": str(checkpoint),
                "dataset": str(tmp_path / "run" / "human.csv")}
    evals = {"episodes": 2, "successes": 1, "success_rate": 0.5}
    out.mkdir()
    (out / "settings.json").write_text(json.dumps(recorded) + "\n")
    (out / "results.json").write_text(json.dumps({"settings": recorded, "before": evals, "after": evals,
                                                  "train": {"episodes": 3}, "finetuned": "f.npz"}) + "\n")
    other = CliRunner().invoke(cli.app, ["finetune", str(checkpoint), "--out", str(out), "--episodes", "3",
                                         "--bc-weight", "0.5"])
    assert other.exit_code == 2 and "bc_weight: the run has 1.0, asked 0.5" in other.output, other.output
    same = CliRunner().invoke(cli.app, ["finetune", str(checkpoint), "--out", str(out), "--episodes", "3"])
    assert same.exit_code == 0 and "before 1/2" in same.output, same.output
