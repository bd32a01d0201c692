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
