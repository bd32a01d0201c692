"""Policies trained in our SITL matched to PX4 SIH (results/transfer/matched-trained/run.py, planned
in docs/camera.md): its config is the matched SITL's with only the plan's changes, and the summary
pairs by policy. Nothing here flies or trains."""

from __future__ import annotations

from pathlib import Path

import pytest

from colcommon.script_module import load_script
from companion.experiment.grid import expand, load_experiment
from sitl.config import load_sitl_config

HERE = Path(__file__).resolve().parents[2] / "results" / "transfer" / "matched-trained"
run = load_script(HERE / "run.py", "matched_trained_run")


def test_the_config_is_the_matched_sitls_with_the_16_trials_and_the_drift_judging_participants(tmp_path: Path) -> None:
    path = tmp_path / "config.toml"
    path.write_text(run.config_text(run.MATCHED_CONFIG.read_text()))
    assert path.read_text() == run.CONFIG.read_text()  # the committed one is made by the runner from today's
    mine, matched = load_experiment(path), load_experiment(run.MATCHED_CONFIG)
    assert sorted(t.key for t in expand(mine.exp)) == sorted(run.T.POLICIES)
    assert mine.exp.eval_runs == 100 and mine.exp.eval_seed == run.T.FIRST_SEED
    assert load_sitl_config(path) == load_sitl_config(run.MATCHED_CONFIG)  # the same vehicle and world
    assert mine.companion.pilot.set_down_by_picture and mine.companion.pilot.judge_drift_by_picture
    assert mine.companion.model_copy(update={"pilot": matched.companion.pilot}) == matched.companion
    with pytest.raises(SystemExit, match="grid has changed"):
        run.config_text(run.MATCHED_CONFIG.read_text().replace("seeds = [0, 1, 2, 3]", "seeds = [0]"))


def test_the_contrasts_pair_by_policy_and_leave_out_what_is_not_flown() -> None:
    shares: dict[str, float | None] = {}
    for key in run.T.POLICIES:
        shares[f"{key}/px4"] = 70.0 if "-col-" in key else 40.0
        shares[f"{key}/matched-sitl"] = 80.0
        shares[f"{key}/plain-px4-aligned"] = 30.0
    shares[f"{run.T.POLICIES[0]}/px4"] = None  # not flown yet: out of every pair it is in
    c = run.contrasts(shares)
    assert (c["gain_of_training_matched/col"]["policies"], c["gain_of_training_matched/col"]["mean_points"]) == (8, 40.0)
    assert (c["gain_of_training_matched/demo"]["policies"], c["gain_of_training_matched/demo"]["mean_points"]) == (7, 10.0)
    assert c["transfer_gap/col"]["mean_points"] == -10.0 and c["transfer_gap/demo"]["mean_points"] == -40.0
    assert c["transfer_gap/all"]["policies"] == 15
    assert (c["col_minus_demo/px4"]["policies"], c["col_minus_demo/px4"]["mean_points"]) == (7, 30.0)
