"""A PPO or fine-tuning folder records the task it flew and is continued only on that task."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from colcommon.numeric_env import read_records
from companion.config import CompanionConfig
from companion.errors import ConfigError
from companion.rl.run_config import RUN_CONFIG, record_run_config, task_summary


def _config(tmp_path: Path, level: float) -> Path:
    path = tmp_path / f"level-{level}.toml"
    path.write_text(f"[sitl.disturbance]\nlevel = {level}\n")
    return path


def test_the_folder_keeps_its_task_and_refuses_another(tmp_path: Path) -> None:
    out = tmp_path / "run"
    out.mkdir()
    first = record_run_config(out, CompanionConfig(), _config(tmp_path, 0.2))
    assert task_summary(first)["disturbance_level"] == 0.2
    assert json.loads((out / RUN_CONFIG).read_text()) == first
    record_run_config(out, CompanionConfig(), _config(tmp_path, 0.2))  # the same task continues
    with pytest.raises(ConfigError, match=r"sitl\.disturbance differ"):
        record_run_config(out, CompanionConfig(), _config(tmp_path, 0.3))
    assert json.loads((out / RUN_CONFIG).read_text()) == first  # nothing overwritten
    assert len(read_records(out)) == 2  # one numeric-environment line per start that went ahead
