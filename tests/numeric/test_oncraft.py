"""CoL on the target vehicle's runner (results/transfer/oncraft.py): its config continues the grid
trial's learner on PX4 SIH as the transfer table flies it (docs/camera.md, "CoL on the target
vehicle"), and its summary pairs each arm by policy. Nothing here flies."""

from __future__ import annotations

import json
from pathlib import Path
from types import ModuleType

import pytest

from colcommon.script_module import load_script
from companion.config import load_companion_config
from companion.experiment.grid import TrainingRun, load_experiment
from companion.experiment.runner import trial_config
from sitl.config import load_sitl_config

TRANSFER = Path(__file__).resolve().parents[2] / "results" / "transfer"


def _load(name: str) -> ModuleType:
    return load_script(TRANSFER / f"{name}.py", f"transfer_{name}")


oncraft = _load("oncraft")


def test_the_committed_configs_are_the_runners() -> None:
    assert oncraft.config_path(0).read_text() == oncraft.config_text(0)
    assert oncraft.config_path(0, drift=True).read_text() == oncraft.config_text(0, drift=True)


def test_the_drift_arms_differ_only_in_how_the_participant_judges_the_drift() -> None:
    """The plan's Amendment 2: the same participant, learner and vehicle; its expert judges the
    drift from the picture."""
    base, drift = (load_companion_config(oncraft.config_path(0, d)) for d in (False, True))
    assert not base.pilot.judge_drift_by_picture and drift.pilot.judge_drift_by_picture
    assert drift.pilot.set_down_by_picture
    assert drift.model_copy(update={"pilot": base.pilot}) == base
    assert load_sitl_config(oncraft.config_path(0, True)) == load_sitl_config(oncraft.config_path(0))
    assert [oncraft.condition(a) for a in oncraft.ARMS] == ["int", "demo", "int", "demo"]
    assert [oncraft.drift_arm(a) for a in oncraft.ARMS] == [False, False, True, True]


def test_the_continued_episodes_learn_as_the_grid_trial_did_on_the_transfer_tables_px4() -> None:
    grid = load_experiment(TRANSFER.parents[0] / "paper-grid" / "config.toml")
    trial = trial_config(grid, TrainingRun("P1", "col", 0, 20, (20,)))
    mine = load_companion_config(oncraft.config_path(0))
    real = load_companion_config(oncraft.transfer.config_path("px4-aligned", "still"))
    assert mine.learner == trial.learner  # budgeted, 40 updates a step, the replicate's seed
    assert mine.session.seed == trial.session.seed == 0  # episode 20 starts from the trial's seed 20
    assert mine.session.model_copy(update={"seed": real.session.seed}) == real.session
    assert mine.perception == real.perception and mine.perception.camera == "render"
    assert mine.session.policy_pad_ned_m == (0.0, 0.0, -1.5)  # the plan's Amendment 1: the policy's frame
    assert load_sitl_config(oncraft.config_path(0)) == load_sitl_config(oncraft.transfer.config_path("px4", "still"))


def test_the_arms_continue_past_the_trials_episodes_without_a_held_out_start() -> None:
    assert sum(oncraft.SITTINGS) == 8 and oncraft.SITTINGS[:2] == (2, 2)  # checkpoints after 2, 4, 8
    last_training_seed = 1000 * 0 + oncraft.FIRST_CONTINUED + sum(oncraft.SITTINGS) - 1
    assert last_training_seed < oncraft.transfer.FIRST_SEED
    assert all(k in oncraft.transfer.POLICIES for k in oncraft.POLICIES)


def test_the_contrasts_are_paired_by_policy_and_missing_cells_left_out(tmp_path: Path,
                                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(oncraft, "OUT", tmp_path / "oncraft")
    monkeypatch.setattr(oncraft.transfer, "EPISODES", tmp_path / "episodes")

    def write(path: Path, on_pad: int) -> None:
        path.parent.mkdir(parents=True, exist_ok=True)
        rows = [{"success": i < on_pad, "true_touchdown_distance_m": 0.1 * (i + 1)} for i in range(20)]
        path.write_text("".join(json.dumps(r) + "\n" for r in rows))

    p1, p2, p3 = oncraft.POLICIES[:3]
    for i, key in enumerate((p1, p2, p3)):
        write(oncraft.transfer.EPISODES / f"{key}-{oncraft.VEHICLE}-still.jsonl", 5 + i)
        write(oncraft.eval_path(key, "int", 4), 15 + 2 * i)  # 50, 55 and 60 points above before
        if key != p3:
            write(oncraft.eval_path(key, "demo", 4), 10 + 2 * i)
    s = oncraft.summary()
    assert s["cells"][f"{p1}/int/4"]["pct"] == 75.0 and s["cells"][f"{p1}/int/4"]["true_distance_median_m"] == 1.05
    lo, hi = s["cells"][f"{p1}/int/4"]["wilson95_pct"]
    assert lo < 75.0 < hi
    before = s["contrasts"]["int-before/4"]
    assert before["policies"] == 3 and before["mean_points"] == 55.0
    assert 50.0 <= before["interval95"][0] <= 55.0 <= before["interval95"][1] <= 60.0
    assert s["contrasts"]["int-demo/4"]["policies"] == 2  # P3 has no demo cell
    assert s["contrasts"]["int-demo/4"]["mean_points"] == 25.0  # (25 + 25) / 2
    assert s["contrasts"]["int-demo/4"]["interval95"] is None  # two policies: no interval drawn
    assert s["contrasts"]["int-demo/2"]["policies"] == 0
    assert s["contrasts"]["int-drift-demo-drift/4"]["policies"] == 0  # no drift arm flown here
    assert "| " + p1 + " | 5/20" in oncraft.table(s)
