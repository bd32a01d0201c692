"""The transfer table's runner (results/transfer/run.py): its configs say what the plan says
(docs/camera.md, "The transfer table"), the committed ones are the runner's, and its summary
pairs each real autopilot with our SITL by policy. Nothing here flies."""

from __future__ import annotations

import json
from pathlib import Path
from types import ModuleType

import pytest

from colcommon.script_module import load_script
from companion.config import load_companion_config
from companion.experiment.grid import load_experiment
from sitl.config import load_sitl_config

TRANSFER = Path(__file__).resolve().parents[2] / "results" / "transfer"


def _load() -> ModuleType:
    return load_script(TRANSFER / "run.py", "transfer_run")


run = _load()


def test_the_plan_has_sixteen_policies_three_vehicles_and_two_airs() -> None:
    assert len(run.POLICIES) == 16 and len(set(run.POLICIES)) == 16
    assert {k.split("-")[1] for k in run.POLICIES} == {"demo", "col"}
    assert run.VEHICLES == ("ours", "ardupilot", "px4") and run.AIRS == {"still": 0.0, "disturbed": 0.2}


def test_the_committed_configs_are_the_runners() -> None:
    for path, text in run.config_texts().items():
        assert path.read_text() == text, path


@pytest.mark.parametrize("air", ["still", "disturbed"])
def test_our_sitl_flies_the_pinned_grids_task_in_that_air(air: str) -> None:
    ours = run.config_path("ours", air)
    grid = run.PAPER_GRID / "config.toml"
    assert load_sitl_config(ours).disturbance.level == run.AIRS[air]
    mine = load_sitl_config(ours).model_dump()
    theirs = load_sitl_config(grid).model_dump()
    mine["disturbance"].pop("level"), theirs["disturbance"].pop("level")
    assert mine == theirs  # nothing else of the vehicle's task changed
    assert load_experiment(ours).companion == load_experiment(grid).companion


@pytest.mark.parametrize("air", ["still", "disturbed"])
def test_the_real_autopilots_fly_the_same_start_box_with_the_truth_camera(air: str) -> None:
    real = run.config_path("real", air)
    cfg = load_companion_config(real)
    sitl = load_sitl_config(real)
    assert cfg.perception.camera == "render" and cfg.session.clock == "vehicle"
    assert cfg.session.start_height_above_pad_m == sitl.world.start_height_above_pad_m == 8.0
    assert cfg.session.start_xy_range_m == sitl.world.start_xy_range_m == 3.0
    assert sitl.disturbance.level == run.AIRS[air]
    assert cfg.session.autopilot_sim_disturbance is (air == "disturbed")


@pytest.mark.parametrize("air", ["still", "disturbed"])
def test_the_aligned_columns_differ_from_the_measured_only_in_the_policys_frame(air: str) -> None:
    measured = load_companion_config(run.config_path("px4", air))
    aligned = load_companion_config(run.config_path("px4-aligned", air))
    assert measured.session.policy_pad_ned_m is None and aligned.session.policy_pad_ned_m == run.POLICY_PAD_NED_M
    assert aligned.model_copy(update={"session": measured.session}) == measured
    assert load_sitl_config(run.config_path("px4-aligned", air)) == load_sitl_config(run.config_path("px4", air))
    assert run.config_path("ardupilot-aligned", air) == run.config_path("px4-aligned", air)


def test_the_gap_is_paired_by_policy_and_missing_cells_are_left_out(tmp_path: Path,
                                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(run, "EPISODES", tmp_path)

    def flown(key: str, vehicle: str, on_pad: int) -> None:
        records = [{"success": i < on_pad} for i in range(20)]
        (tmp_path / f"{key}-{vehicle}-still.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))

    cols = [k for k in run.POLICIES if "-col-" in k]
    for i, key in enumerate(cols[:3]):
        flown(key, "ours", 20 - i)  # 100, 95, 90 %
        flown(key, "ardupilot", 18 - i)  # each 10 points below its own policy on ours
    flown(cols[3], "ours", 20)  # no ArduCopter cell: not in the pairs
    s = run.summary()
    gap = s["gaps"]["ardupilot/still/col"]
    assert gap["policies"] == 3 and gap["mean_gap_points"] == -10.0
    assert s["gaps"]["px4/still/col"]["policies"] == 0
    assert "| P1-col-20-s0 | 100 | 90 |" in run.table(s)
    assert s["col_minus_demo"]["ours/still"]["pairs"] == 0  # no Demo cell flown: nothing to pair
    flown("P1-demo-20-s0", "ours", 10)
    pair = run.summary()["col_minus_demo"]["ours/still"]
    assert pair["pairs"] == 1 and pair["mean_points"] == 50.0  # P1-col-20-s0 100 % - P1-demo-20-s0 50 %
    flown("P1-col-20-s0", "px4", 4)
    flown("P1-col-20-s0", "px4-aligned", 9)
    moved = run.summary()["frame_moved"]
    assert moved["px4-aligned/still/col"] == {"pairs": 1, "mean_points": 25.0, "interval95": None}  # 45 % - 20 %
    assert moved["px4-aligned/still/all"] == moved["px4-aligned/still/col"]
    assert moved["px4-aligned/still/demo"]["pairs"] == 0  # by condition, as the gaps
    assert moved["ardupilot-aligned/still/all"]["pairs"] == 0
