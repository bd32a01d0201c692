"""The pad-speed sweep's runner and summary (results/moving-pad/sweep/): the pure parts, so that
hours of runs are not spent on a wrong config or read by a wrong rule. Nothing here flies."""

from __future__ import annotations

import json
import math
from pathlib import Path
from types import ModuleType

import pytest

from colcommon.script_module import load_script
from companion.config import load_companion_config
from companion.experiment.grid import TRAIN_CONDITIONS, load_experiment
from companion.statistics import wilson_interval
from sitl.config import load_sitl_config
from sitl.disturbance import EpisodeDisturbance

SWEEP = Path(__file__).resolve().parents[2] / "results" / "moving-pad" / "sweep"


def _load(name: str) -> ModuleType:
    return load_script(SWEEP / f"{name}.py", f"moving_pad_sweep_{name}")


run = _load("run")
summarise = _load("summarise")


@pytest.fixture(scope="module")
def written(tmp_path_factory: pytest.TempPathFactory) -> dict[Path, str]:
    """Every config of every speed, written to a temporary folder as the configs step writes them."""
    folder = tmp_path_factory.mktemp("configs")
    paper = run.PAPER.read_text()
    out = {}
    for speed in run.SPEEDS:
        for path, text in run.config_texts(paper, speed).items():
            (folder / path.name).write_text(text)
            out[folder / path.name] = text
    return out


def test_the_runner_and_the_summary_name_the_same_speeds_and_arms() -> None:
    assert run.SPEEDS == summarise.SPEEDS
    assert tuple(run.ARMS) == tuple(summarise.ARMS)


def test_set_key_adds_to_a_table_the_file_has_instead_of_naming_it_twice() -> None:
    text = "[a]\nx = 1  # one\n\n# about b\n[b]\ny = 2\n"
    added = run.set_key(text, "a", "z", True)
    assert added.count("[a]") == 1 and added.index("z = true") < added.index("# about b")
    assert run.set_key(text, "b", "y", 3).count("y =") == 1
    assert run.set_key(text, "c", "w", "s").endswith('[c]\nw = "s"\n')


def test_every_config_loads_and_has_its_keys(written: dict[Path, str]) -> None:
    assert len(written) == 7 * len(run.SPEEDS)
    for path, text in written.items():
        kind = run.kind_of(path)
        speed = path.stem.split("-speed-")[-1] if kind != "policies" else path.stem.removeprefix("policies-")
        run.check_config(text, run.expected_tables(kind, speed))
        sitl, companion = load_sitl_config(path), load_companion_config(path)
        assert sitl.disturbance.level == 0.2 and sitl.world.roof_carries
        assert sitl.world.vehicle_velocity_ne_m_s == (0.0, 0.0) and sitl.world.vehicle_turn_rate_rad_s == 0.0
        assert sitl.world.vehicle_speed_change == 0.0  # straight on at a steady speed
        assert companion.pilot.lead_moving_pad == (kind in ("colour-pad-lead", "policies"))
        board = "aruco-disc" if kind.endswith("-disc") else "aruco" if kind.startswith("precland") else "none"
        assert sitl.camera.pad_marker == board
        assert sitl.personality.autopilot == ("ardupilot" if kind.startswith("precland-ardupilot") else "px4")


def test_the_policies_grid_is_p1_to_p4_at_20_with_two_replicates(written: dict[Path, str]) -> None:
    path = next(p for p in written if p.name == "policies-1.0.toml")
    exp = load_experiment(path).exp
    assert exp.participants == ("P1", "P2", "P3", "P4") and exp.conditions == ("demo", "col", "colplus")
    assert exp.interactions == (20,) and exp.seeds == (0, 1)
    assert (exp.eval_runs, exp.eval_seed, exp.updates_per_step, exp.eval_inprocess) == (100, 100_000, 40, True)
    assert "colplus" in TRAIN_CONDITIONS and run.parse_conditions("demo,col,colplus")[-1] == "colplus"
    assert len(run.expected_trials(("demo", "col"))) == 16


@pytest.mark.parametrize("speed", ["0", "0.25", "0.5", "0.75", "1.0", "1.5"])
def test_the_pad_drives_at_exactly_the_speed_in_a_random_direction(speed: str, written: dict[Path, str]) -> None:
    path = next(p for p in written if p.name == f"colour-pad-speed-{speed}.toml")
    cfg = load_sitl_config(path).disturbance
    draws = [EpisodeDisturbance.draw(cfg, 100_000 + k).vehicle_velocity_ne_m_s for k in range(20)]
    assert all(math.isclose(math.hypot(*v), float(speed), abs_tol=1e-12) for v in draws)
    if float(speed) > 0:
        assert len({round(math.atan2(v[1], v[0]), 6) for v in draws}) == 20  # only the direction is drawn


def test_fly_commands_name_the_arm_config_and_starts() -> None:
    cmd = run.fly_command("expert-lead", "0.5", run.DEFAULT_RUNS / "x", 100)
    assert cmd[1:7] == ["fly", "--pilot", "expert", "--condition", "demo", "--no-learn"]
    assert "results/moving-pad/sweep/configs/colour-pad-lead-speed-0.5.toml" in cmd
    assert cmd[cmd.index("--seed") + 1] == "100000" and "--no-pictures" in cmd and "--connect" not in cmd
    ext = {"connect": "udpin:127.0.0.1:1", "simulator": "127.0.0.1:2", "camera": "colf://127.0.0.1:3"}
    plain = run.fly_command("precland-px4-plain", "1.0", run.DEFAULT_RUNS / "x", 2, ext)
    assert "results/moving-pad/sweep/configs/precland-px4-speed-1.0.toml" in plain and "--lockstep" in plain
    assert run.ARMS["precland-px4-plain"].sitl_config == "colour-pad"
    assert "--realtime" in run.fly_command("precland-ardupilot", "1.0", run.DEFAULT_RUNS / "x", 2, ext)
    params = {name: value for name, value, _ in run.ARMS["precland-ardupilot"].params}
    assert params == {"PLND_ENABLED": 1.0, "PLND_TYPE": 1.0, "PLND_OPTIONS": 1.0}  # bit 0: the moving target
    assert not any(p.startswith("/") for p in cmd)
    disc = run.fly_command("precland-ardupilot-disc", "1.0", run.DEFAULT_RUNS / "x", 2, ext)
    assert "results/moving-pad/sweep/configs/precland-ardupilot-disc-speed-1.0.toml" in disc and "--realtime" in disc
    assert run.ARMS["precland-ardupilot-disc"].params == run.ARMS["precland-ardupilot"].params


def test_the_policies_fly_the_board_in_the_colour_pad_unless_told_otherwise() -> None:
    args = run.parser().parse_args(["policies", "1.0"])
    assert args.board == "aruco-disc"
    assert run.parser().parse_args(["policies", "1.0", "--no-aruco"]).board is None
    cmd = run.eval_command(Path("runs/x.npz"), "0.5", run.DEFAULT_RUNS / "x", 100, args.board)
    assert "results/moving-pad/sweep/configs/precland-px4-disc-speed-0.5.toml" in cmd
    assert "precland-px4-speed-0.5.toml" in " ".join(run.eval_command(Path("x.npz"), "0.5", Path("y"), 100, "aruco"))


def test_a_grid_trained_again_must_give_the_committed_lines() -> None:
    committed = run.finished_trials(run.POLICIES / "1.0" / "results.jsonl")
    run.check_reproduced(committed, "1.0")  # the same lines: passes
    key = next(iter(committed))
    changed = {key: {**committed[key], "eval_successes": committed[key]["eval_successes"] + 1}}
    with pytest.raises(SystemExit, match=key):
        run.check_reproduced(changed, "1.0")


def test_small_checks_never_land_in_the_committed_episodes(tmp_path: Path) -> None:
    assert run.kept_path("expert-speed-0", 100, tmp_path) == run.EPISODES / "expert-speed-0.jsonl"
    assert run.kept_path("expert-speed-0", 2, tmp_path).is_relative_to(tmp_path)
    assert run.speed_name("1") == "1.0"


def test_records_lose_machine_paths() -> None:
    text = json.dumps({"command": [str(run.ROOT / ".venv/bin/col"), "--out", "/elsewhere/x/runs/moving-pad-sweep/p"]})
    assert json.loads(run.strip_paths(text))["command"] == [".venv/bin/col", "--out", "runs/moving-pad-sweep/p"]


def test_wilson_interval_as_the_summary_reports_it() -> None:
    low, high = wilson_interval(50, 100)
    assert round(100 * low, 2) == 40.38 and round(100 * high, 2) == 59.62
    assert summarise.describe([_episode(0, True)] * 10)["wilson95_pct"] == [72.25, 100.0]


def _episode(seed: int, success: bool, outcome: str = "touchdown") -> dict:
    return {"seed": seed, "success": success, "outcome": outcome, "sim_time_s": 20.0 + seed % 7,
            "touchdown_distance_m": (0.1 if success else 0.9) if outcome == "touchdown" else None}


def _write(folder: Path, name: str, wins: int, n: int = 10, outcome: str = "timeout") -> None:
    lines = [_episode(k, k < wins, "touchdown" if k < wins else outcome) for k in range(n)]
    (folder / f"{name}.jsonl").write_text("".join(json.dumps(r) + "\n" for r in lines))


def test_a_partial_sweep_is_summarised_and_says_what_is_missing(tmp_path: Path) -> None:
    _write(tmp_path, "precland-px4-speed-1.0", 3, outcome="fence")
    _write(tmp_path, "precland-ardupilot-speed-1.0", 5)
    _write(tmp_path, "expert-speed-0", 10)
    for k, key in enumerate(summarise.expected_trial_keys("col")):
        _write(tmp_path, f"{key}-speed-1.0-colour", 9 + k % 2)
    s = summarise.summary(tmp_path)
    px4 = s["speeds"]["1.0"]["arms"]["precland-px4"]
    assert (px4["success_rate_pct"], px4["fence_exits"], px4["timeouts"]) == (30.0, 7, 0)
    assert px4["touchdown_distance_m_median"] == 0.1 and px4["time_to_land_s_median"] == 21.0
    col = s["speeds"]["1.0"]["policies"]["col"]["colour"]
    assert col["trials"] == 8 and col["mean_success_pct"] == 95.0 and col["interval"] == "BCa"
    assert col["interval95_pct"][0] < 95.0 < col["interval95_pct"][1]
    assert col["pooled"]["episodes"] == 80 and col["pooled"]["successes"] == 76
    assert "expert-lead at 1.0 m/s" in s["missing"] and "CoL@20 on the colour pad at 1.0 m/s" not in " ".join(s["missing"])
    assert "Demo@20 on the colour pad at 1.0 m/s: all 8 trials" in s["missing"]
    wins = s["question"]["learning_wins"]["col/colour"]
    assert wins["speeds"] == ["1.0"] and "0" in wins["undecided"]
    md = summarise.table(s)
    assert "## Not run yet" in md and "## Pad at 1.0 m/s" in md and "## Pad at 0.5 m/s" not in md
    assert "expert-lead-px4-real at 0.5 m/s" in s["missing"]


def test_the_real_autopilots_arms_are_scored_by_the_truths_distance_apart_from_the_question(tmp_path: Path) -> None:
    rows = [{**_episode(k, k < 15), "touchdown_distance_m": 0.9, "true_touchdown_distance_m": 0.2 + 0.01 * k}
            for k in range(20)]
    (tmp_path / "precland-ardupilot-real-speed-1.0.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    s = summarise.summary(tmp_path)
    real = s["speeds"]["1.0"]["real_arms"]["precland-ardupilot-real"]
    assert real["success_rate_pct"] == 75.0 and real["touchdown_distance_m_median"] == pytest.approx(0.295)
    assert "precland-ardupilot-real" not in s["speeds"]["1.0"]["arms"]  # not one of the question's arms
    assert "precland-ardupilot-real at 1.0 m/s" not in s["missing"]
    md = summarise.table(s)
    assert "## On the real autopilots' SITL (Amendment 4)" in md
    assert "| precland, real ArduCopter, PLND with the moving-target option | 1.0 | 75.0 %" in md


def _speeds(precland: tuple[int, int], policy: list[float]) -> dict:
    """One speed's block, as summary() makes it, from two precland arms' wins of 100 and a
    condition's per-trial rates."""
    arms = {arm: summarise.describe([_episode(k, k < w) for k in range(100)])
            for pad_arms in summarise.PRECLAND_FOR_PAD.values() for arm, w in zip(pad_arms, precland, strict=True)}
    cell = summarise.over_trials(policy)
    return {"1.0": {"arms": arms, "policies": {"col": {"colour": cell, "aruco-disc": cell}}}}


def test_learning_wins_needs_90_percent_and_both_autopilots_at_50_or_below() -> None:
    assert summarise.learning_wins(_speeds((50, 10), [90.0] * 8), "col", "colour")["speeds"] == ["1.0"]
    assert summarise.learning_wins(_speeds((51, 10), [95.0] * 8), "col", "colour")["speeds"] == []
    assert summarise.learning_wins(_speeds((0, 0), [89.0, 90.0] * 4), "col", "colour")["speeds"] == []
    assert summarise.learning_wins(_speeds((50, 10), [90.0] * 8), "col", "aruco-disc")["speeds"] == ["1.0"]


def test_the_board_in_the_pad_is_asked_against_precland_on_that_board_only() -> None:
    block = _speeds((100, 100), [60.0] * 8)
    block["1.0"]["arms"]["precland-px4-disc"] = summarise.describe([_episode(k, k < 10) for k in range(100)])
    block["1.0"]["arms"]["precland-ardupilot-disc"] = summarise.describe([_episode(k, k < 10) for k in range(100)])
    block["1.0"]["policies"]["col"]["aruco-disc"] = summarise.over_trials([95.0] * 8)
    q = summarise.question(block)
    assert q["learning_wins"]["col/aruco-disc"]["speeds"] == ["1.0"]  # its own board's precland fails
    assert q["learning_wins"]["col/colour"]["speeds"] == []
    assert "precland-px4 over col/aruco-disc" not in q["precland_better"]
    assert q["precland_better"]["precland-px4 over col/colour"]["speeds"] == ["1.0"]
    assert not any(k.endswith("/aruco") for k in q["learning_wins"])  # the void pad answers nothing


def test_precland_is_better_only_where_its_wilson_interval_is_above_the_policies() -> None:
    above = _speeds((100, 100), [60.0, 70.0, 80.0, 75.0, 65.0, 70.0, 72.0, 68.0])
    assert summarise.precland_better(above, "precland-px4", "col", "colour")["speeds"] == ["1.0"]
    overlapping = _speeds((90, 90), [80.0, 95.0, 90.0, 85.0, 100.0, 70.0, 90.0, 88.0])
    assert summarise.precland_better(overlapping, "precland-px4", "col", "colour")["speeds"] == []
    assert summarise.over_trials([96.0] * 8)["interval95_pct"] == [96.0, 96.0]  # all equal: that value
    below = _speeds((100, 100), [96.0] * 8)  # 100/100: Wilson [96.3, 100]
    assert summarise.precland_better(below, "precland-px4", "col", "colour")["speeds"] == ["1.0"]
    assert summarise.precland_better(_speeds((100, 100), [97.0] * 8), "precland-px4", "col", "colour")["speeds"] == []
    assert summarise.precland_better(_speeds((100, 100), [97.0]), "precland-px4", "col", "colour")["undecided"] == ["1.0"]


@pytest.mark.parametrize("arm", ["precland", "expert-lead"])
@pytest.mark.parametrize("speed", ["0.5", "1.0", "1.5"])
def test_the_real_autopilots_arms_see_the_board_in_the_pad_that_drives_at_the_speed_and_land_by_truth(
        speed: str, arm: str, tmp_path: Path) -> None:
    path = tmp_path / run.real_config_path(speed, arm).name
    path.write_text(run.real_config_text(speed, arm))
    cfg, sitl = load_companion_config(path), load_sitl_config(path)
    assert cfg.perception.camera == "render" and sitl.camera.pad_marker == "aruco-disc"  # Amendment 3's board
    assert cfg.session.autopilot_sim_disturbance and cfg.session.clock == "vehicle"
    assert cfg.session.touchdown_by_truth_contact  # Amendment 4: the rendered pad is no surface
    assert cfg.pilot.lead_moving_pad == (arm == "expert-lead")
    drive = EpisodeDisturbance.draw(sitl.disturbance, 100_000).vehicle_velocity_ne_m_s
    assert math.hypot(*drive) == pytest.approx(float(speed), abs=1e-12)
    assert sitl.world.vehicle_height_m == 0.0 and cfg.session.pad_ned_m == (0.0, 0.0, 0.0)


def test_the_real_autopilots_arms_keep_20_starts_and_checks_elsewhere(tmp_path: Path) -> None:
    assert run.kept_path("expert-lead-px4-real-speed-0.5", 20, tmp_path, planned=run.REAL_STARTS).parent == run.EPISODES
    assert run.kept_path("expert-lead-px4-real-speed-0.5", 2, tmp_path, planned=run.REAL_STARTS).is_relative_to(tmp_path)
    assert run.parser().parse_args(["fly-real", "px4", "0.5"]).episodes == 20
    assert run.REAL_ARMS["expert-lead"] == run.EXPERT and run.REAL_ARMS["precland"] == run.PRECLAND


def test_a_grid_trained_again_is_kept_beside_the_first_not_over_it(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(run, "POLICIES", tmp_path / "policies")
    out = tmp_path / "run"
    out.mkdir()
    (out / "results.jsonl").write_text('{"first": true}\n')
    assert run.keep_grid(out, "0.5") == tmp_path / "policies" / "0.5"
    (out / "results.jsonl").write_text('{"again": true}\n')
    assert run.keep_grid(out, "0.5") == tmp_path / "policies" / "0.5" / "retrained"
    assert (tmp_path / "policies" / "0.5" / "results.jsonl").read_text() == '{"first": true}\n'
    assert (tmp_path / "policies" / "0.5" / "retrained" / "results.jsonl").read_text() == '{"again": true}\n'


def test_records_keep_every_line_already_kept_when_a_run_folder_holds_another_run(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    here, episodes, runs = tmp_path / "here", tmp_path / "episodes", tmp_path / "runs"
    here.mkdir(), episodes.mkdir(), (runs / "expert-speed-0").mkdir(parents=True)
    monkeypatch.setattr(run, "HERE", here)
    monkeypatch.setattr(run, "EPISODES", episodes)
    (episodes / "expert-speed-0.jsonl").write_text("{}\n")
    first = json.dumps({"arm": "expert-speed-0", "commit": "a"}, sort_keys=True)
    (here / "environment.jsonl").write_text(first + "\n")
    (runs / "expert-speed-0" / "environment.jsonl").write_text(json.dumps({"commit": "b"}) + "\n")
    run.environment_records(runs)
    lines = (here / "environment.jsonl").read_text().splitlines()
    assert lines[0] == first and json.loads(lines[1]) == {"arm": "expert-speed-0", "commit": "b"}
    run.environment_records(runs)  # again: nothing doubled
    assert (here / "environment.jsonl").read_text().splitlines() == lines
