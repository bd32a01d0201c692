"""Our SITL matched to PX4 SIH (results/transfer/matched/run.py, the transfer table's Amendment 2
in docs/camera.md): its columns differ from the table's own SITL column only by what the plan
says, the calibration keeps the closest response, and the summary pairs by policy. Nothing here
flies."""

from __future__ import annotations

import json
from pathlib import Path
from types import ModuleType

import pytest

from colcommon.script_module import load_script
from companion.experiment.grid import load_experiment
from sitl.config import load_sitl_config

MATCHED = Path(__file__).resolve().parents[2] / "results" / "transfer" / "matched"
FIT = {"sitl_estimator": {"velocity_error_std_m_s": 0.21, "velocity_error_tau_s": 2.5, "position_pull_tau_s": 1.1},
       "vel_cmd_tau_s": 0.75}


def _load() -> ModuleType:
    return load_script(MATCHED / "run.py", "matched_run")


run = _load()


@pytest.mark.parametrize("column", ["ours-ground", "ours-est", "ours-matched"])
def test_each_column_is_ours_still_with_only_the_plans_changes(tmp_path: Path, column: str) -> None:
    path = tmp_path / f"{column}.toml"
    path.write_text(run.column_text(column, FIT))
    mine = load_sitl_config(path).model_dump()
    ours = load_sitl_config(run.TRANSFER / "configs" / "ours-still.toml").model_dump()
    assert mine["world"]["vehicle_height_m"] == 0.0
    est = mine["estimator"]
    assert (est["velocity_error_std_m_s"] > 0) == (column != "ours-ground")
    assert mine["autopilot"]["vel_cmd_tau_s"] == (0.75 if column == "ours-matched" else 0.0)
    for m in (mine, ours):
        m["world"].pop("vehicle_height_m")
        for key in FIT["sitl_estimator"]:
            m["estimator"].pop(key)
        m["autopilot"].pop("vel_cmd_tau_s")
    assert mine == ours
    companion = load_experiment(path).companion
    assert tuple(companion.session.pad_ned_m) == (0.0, 0.0, 0.0)
    base = load_experiment(run.TRANSFER / "configs" / "ours-still.toml").companion
    assert companion.model_copy(update={"session": base.session}) == base


def test_a_matched_column_needs_the_calibration_first() -> None:
    with pytest.raises(SystemExit, match="calibrate first"):
        run.column_text("ours-est", None)


def test_the_closest_gain_curve_is_the_one_kept() -> None:
    def response(gains: list[float]) -> dict:
        return {"by_lag": [{"lag_s": 0.1 * i, "horizontal_gain": g} for i, g in enumerate(gains)]}

    px4 = response([0.2, 0.4, 0.6, 0.7])
    assert run.curve_distance(response([0.2, 0.4, 0.6, 0.7]), px4) == 0.0
    near, far = response([0.25, 0.45, 0.6, 0.7]), response([0.9, 0.9, 0.8, 0.6])
    assert run.curve_distance(near, px4) < run.curve_distance(far, px4)
    with pytest.raises(ValueError):
        run.curve_distance(response([0.1, 0.2]), px4)


def test_the_summary_pairs_each_column_with_px4_by_policy(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    mine, table = tmp_path / "matched", tmp_path / "table"
    mine.mkdir(), table.mkdir()
    monkeypatch.setattr(run, "EPISODES", mine)
    monkeypatch.setattr(run.T, "EPISODES", table)

    def write(folder: Path, key: str, column: str, on_pad: int) -> None:
        lines = [json.dumps({"success": i < on_pad}) for i in range(20)]
        (folder / f"{key}-{column}-still.jsonl").write_text("\n".join(lines) + "\n")

    keys = run.T.POLICIES[:4]
    for i, key in enumerate(keys):
        write(table, key, "ours", 20)  # ours: 100 %
        write(table, key, "px4", 4 + i)  # px4: 20-35 %
        write(mine, key, "ours-matched", 5 + i)  # matched: 5 points above px4
    s = run.summary()
    matched = s["columns"]["ours-matched"]
    assert matched["minus_px4"]["policies"] == 4 and matched["minus_px4"]["mean_points"] == 5.0
    # |ours - px4| is 65-80 points, |matched - px4| 5: the error falls by 60-75, 67.5 on average
    assert matched["absolute_error_reduction"]["mean_points"] == 67.5
    assert s["columns"]["ours-est"]["minus_px4"]["policies"] == 0  # not flown: not counted
    assert "| ours-matched | 4 | 5.0 |" in run.table(s)


def test_the_committed_columns_are_the_runners_from_the_committed_fit() -> None:
    fit = json.loads(run.FIT.read_text())
    assert fit["vel_cmd_tau_s"] in run.TAUS_S
    for column in run.COLUMNS:
        assert run.config_path(column).read_text() == run.column_text(column, fit), column
