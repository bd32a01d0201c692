"""The experiment grid: expansion, resumable results, report statistics, a real trial."""

from __future__ import annotations

import dataclasses
import json
import math
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from companion.config import CompanionConfig
from companion.errors import ConfigError, DatasetCorrupt
from companion.experiment.grid import (
    ExperimentConfig,
    ExperimentSetup,
    TrainingRun,
    Trial,
    expand,
    load_experiment,
    plan,
)
from companion.experiment.report import markdown, mean_se, summarise, write_report
from companion.experiment.results import ResultsFile, TrialResult
from companion.experiment.runner import run_grid, run_training, run_trial, trial_config
from companion.learning.checkpoint import load_checkpoint

REPO = Path(__file__).resolve().parents[2]


def setup_of(**grid: object) -> ExperimentSetup:
    return ExperimentSetup(ExperimentConfig(**grid), CompanionConfig())  # type: ignore[arg-type]


def result(trial: Trial, fingerprint: str = "f", successes: int = 10, runs: int = 20, samples: int = 100,
           status: str = "ok") -> TrialResult:
    return TrialResult(trial=trial, fingerprint=fingerprint, status=status,  # type: ignore[arg-type]
                       eval_runs=runs, eval_successes=successes, human_samples=samples)


def test_the_paper_grid_expands_to_48_distinct_trials_longest_first() -> None:
    setup = load_experiment(REPO / "configs" / "experiment.toml")
    trials = expand(setup.exp)
    assert len(trials) == 4 * 3 * 4 and len({t.key for t in trials}) == 48
    assert {t.condition for t in trials} == {"demo", "int", "col"}
    assert {t.participant for t in trials} == {"P1", "P2", "P3", "P4"}
    assert [t.interactions for t in trials] == sorted((t.interactions for t in trials), reverse=True)
    assert setup.exp.eval_runs == 100 and setup.companion.learner.mode == "budgeted"


def test_the_paper_size_grid_has_four_replicates_and_84_training_episodes_per_unit() -> None:
    setup = load_experiment(REPO / "configs" / "paper.toml")
    assert len(expand(setup.exp)) == 4 * 3 * 4 * 4 and setup.exp.seeds == (0, 1, 2, 3)
    assert sum(r.episodes for r in plan(setup.exp)) == 84 * 4 * 4
    assert setup.exp.eval_runs == 100 and setup.companion.perception.frame_timeout_s == 2.0


def test_the_quick_grid_is_small() -> None:
    setup = load_experiment(REPO / "configs" / "experiment_quick.toml")
    assert [t.key for t in expand(setup.exp)] == ["P1-demo-02-s0", "P1-col-02-s0"]
    assert setup.exp.eval_runs == 3


@pytest.mark.parametrize("table", [
    'participants = ["P9"]', "interactions = [0, 4]", "seeds = [1, 1]", "seeds = [100]",
    'conditions = ["eval"]', "eval_runs = 0", "typo_key = 1",
])
def test_bad_experiment_tables_are_config_errors(tmp_path: Path, table: str) -> None:
    path = tmp_path / "exp.toml"
    path.write_text(f"[experiment]\n{table}\n")
    with pytest.raises(ConfigError):
        load_experiment(path)


def test_replicates_use_their_own_training_starts_and_a_budgeted_learner() -> None:
    setup = setup_of(updates_per_step=7)
    cfg = trial_config(setup, Trial("P2", "col", 8, 3))
    assert cfg.learner.mode == "budgeted" and cfg.learner.updates_per_step == 7
    assert cfg.learner.seed == cfg.session.seed == 3000
    assert Trial("P2", "col", 8, 0).start_seed + 20 <= Trial("P2", "col", 8, 1).start_seed < 100_000


def test_fingerprint_follows_evaluation_and_config_but_not_the_grid_extent() -> None:
    base = setup_of().fingerprint()
    assert setup_of(participants=("P1",), interactions=(4,)).fingerprint() == base
    assert setup_of(eval_runs=50).fingerprint() != base
    other = CompanionConfig().model_copy(update={"learner": CompanionConfig().learner.model_copy(update={"learning_rate": 1e-3})})
    assert ExperimentSetup(ExperimentConfig(), other).fingerprint() != base
    assert ExperimentSetup(ExperimentConfig(), CompanionConfig(), sitl_tables='{"world": {}}').fingerprint() != base


def test_settings_added_later_keep_committed_fingerprints_at_their_defaults() -> None:
    """The ensemble size and [companion.ask] came after results/paper-grid was committed."""
    committed = json.loads((Path(__file__).parents[2] / "results/paper-grid/experiment.json").read_text())
    assert load_experiment(Path(__file__).parents[2] / "configs/paper.toml").fingerprint() == committed["fingerprint"]
    base = setup_of().fingerprint()
    learner = CompanionConfig().learner.model_copy(update={"ensemble_members": 5})
    ensemble = CompanionConfig().model_copy(update={"learner": learner})
    assert ExperimentSetup(ExperimentConfig(), ensemble).fingerprint() != base
    asking = ensemble.model_copy(update={"ask": ensemble.ask.model_copy(update={"enabled": True})})
    assert ExperimentSetup(ExperimentConfig(), asking).fingerprint() not in (base, ExperimentSetup(
        ExperimentConfig(), ensemble).fingerprint())


def test_results_file_round_trips_skips_a_torn_last_line_and_refuses_a_bad_middle_one(tmp_path: Path) -> None:
    f = ResultsFile(tmp_path / "results.jsonl")
    a, b = result(Trial("P1", "demo", 4, 0)), result(Trial("P1", "col", 4, 0), successes=20)
    f.append(a)
    f.append(b)
    assert f.load() == [a, b]
    with f.path.open("a") as fh:
        fh.write('{"trial": {"participant": "P1", "cond')  # a crash while writing
    assert f.load() == [a, b]
    c = result(Trial("P1", "int", 4, 0))
    f.append(c)  # the torn line is cut first
    assert f.load() == [a, b, c]
    f.path.write_text(f.path.read_text().replace(json.dumps(b.to_json_dict()), "garbage"))
    with pytest.raises(DatasetCorrupt, match="delete that line"):
        f.load()


def test_finished_counts_only_ok_results_with_the_same_fingerprint(tmp_path: Path) -> None:
    f = ResultsFile(tmp_path / "results.jsonl")
    t1, t2, t3 = Trial("P1", "demo", 4, 0), Trial("P1", "col", 4, 0), Trial("P1", "int", 4, 0)
    f.append(result(t1, "f"))
    f.append(result(t2, "f", status="error"))
    f.append(result(t3, "old"))
    assert set(f.finished("f")) == {t1.key}


def fake_run(setup: ExperimentSetup, run: TrainingRun, out_dir: Path) -> list[TrialResult]:
    """Runs in a worker process: leaves a mark per trial it answers; P2's int runs fail."""
    (out_dir / "calls").mkdir(exist_ok=True)
    for trial in run.trials:
        with (out_dir / "calls" / trial.key).open("a") as fh:
            fh.write("x")
    if run.participant == "P2" and run.condition == "int":
        raise RuntimeError("the SITL did not start")
    return [result(t, setup.fingerprint(), successes=t.interactions, samples=10 * t.interactions)
            for t in run.trials]


def calls(out_dir: Path) -> dict[str, int]:
    return {p.name: len(p.read_text()) for p in (out_dir / "calls").iterdir()} if (out_dir / "calls").exists() else {}


def test_grid_runs_in_worker_processes_and_resumes_without_redoing_finished_trials(tmp_path: Path) -> None:
    setup = setup_of(participants=("P1", "P2"), conditions=("demo", "int"), interactions=(4, 8), eval_runs=20)
    done_before = Trial("P1", "demo", 8, 0)
    ResultsFile(tmp_path / "results.jsonl").append(result(done_before, setup.fingerprint(), successes=7))
    first = run_grid(setup, tmp_path, workers=2, progress=False, run_fn=fake_run)
    assert done_before.key not in calls(tmp_path)  # finished before the crash: not run again
    assert len(calls(tmp_path)) == 7 and set(calls(tmp_path).values()) == {1}
    assert len(first) == 6  # 8 trials, 2 failed
    assert next(r for r in first if r.trial == done_before).eval_successes == 7
    lines = (tmp_path / "results.jsonl").read_text().splitlines()
    assert sum('"status": "error"' in line for line in lines) == 2
    errors = [json.loads(line)["error"] for line in lines if '"status": "error"' in line]
    assert all("RuntimeError: the SITL did not start (at test_grid.py:" in e and "in fake_run" in e for e in errors)
    second = run_grid(setup, tmp_path, workers=2, progress=False, run_fn=fake_run)
    assert {k: v for k, v in calls(tmp_path).items() if v > 1} == {"P2-int-08-s0": 2, "P2-int-04-s0": 2}
    assert [r.trial for r in second] == [r.trial for r in first]
    assert json.loads((tmp_path / "experiment.json").read_text())["already_done"] == 6


def test_demo_and_int_train_once_to_the_largest_count_col_once_per_count() -> None:
    exp = ExperimentConfig(participants=("P1", "P2"), interactions=(4, 8, 12, 20), seeds=(0, 1))
    runs = plan(exp)
    assert sorted(t.key for r in runs for t in r.trials) == sorted(t.key for t in expand(exp))
    prefix = [r for r in runs if r.condition != "col"]
    assert len(prefix) == 2 * 2 * 2 and {r.evaluated_at for r in prefix} == {(4, 8, 12, 20)}
    assert {r.episodes for r in prefix} == {20}
    col = [r for r in runs if r.condition == "col"]
    assert sorted(r.evaluated_at for r in col) == sorted([(n,) for n in (4, 8, 12, 20)] * 4)
    # per (participant, replicate): 20 + 20 + (4 + 8 + 12 + 20) = 84 training episodes, not 132
    assert sum(r.episodes for r in runs) == 84 * 4
    assert [r.episodes for r in runs] == sorted((r.episodes for r in runs), reverse=True)
    assert runs[0].key == runs[0].trials[-1].key


def test_a_resumed_plan_trains_only_as_far_as_the_missing_counts() -> None:
    exp = ExperimentConfig(participants=("P1",), conditions=("demo",), interactions=(4, 8, 20))
    missing = [Trial("P1", "demo", 4, 0), Trial("P1", "demo", 8, 0)]
    assert plan(exp, missing) == [TrainingRun("P1", "demo", 0, 8, (4, 8))]
    whole = ExperimentConfig(participants=("P1",), conditions=("demo",), interactions=(4, 8), prefix_evaluation=False)
    assert sorted(r.episodes for r in plan(whole)) == [4, 8]
    assert TrainingRun("P1", "demo", 0, 8, (4, 8)).only(4) == TrainingRun("P1", "demo", 0, 8, (4,))
    assert TrainingRun("P1", "demo", 0, 8, (4,)).key == "P1-demo-08-s0"  # the run's folder
    for bad in ((4, 9), (8, 4), (4, 4), (0, 8)):
        with pytest.raises(ConfigError):
            TrainingRun("P1", "demo", 0, 8, bad)
    with pytest.raises(ConfigError):
        TrainingRun("P1", "col", 0, 8, (4, 8))  # CoL@4 is not a prefix of CoL@8


def test_mean_and_standard_error() -> None:
    assert mean_se([50.0, 70.0, 90.0]) == pytest.approx((70.0, 20.0 / math.sqrt(3)))
    assert mean_se([42.0]) == (42.0, None)
    with pytest.raises(ValueError):
        mean_se([])


def test_report_table_statistics_and_paper_numbers_on_hand_made_results(tmp_path: Path) -> None:
    rs = []
    for p, demo_ok, col_ok, demo_n, col_n in (("P1", 10, 18, 2000, 1200), ("P2", 14, 19, 2200, 1400), ("P3", 12, 20, 2400, 1000)):
        rs.append(result(Trial(p, "demo", 20, 0), successes=demo_ok, samples=demo_n))
        rs.append(result(Trial(p, "col", 20, 0), successes=col_ok, samples=col_n))
    rs.append(result(Trial("P4", "col", 20, 0), successes=0, status="error"))  # not counted
    cells = summarise(rs)
    assert [(c.condition, c.n) for c in cells] == [("demo", 3), ("col", 3)]
    demo, col = cells
    assert demo.completion_pct == pytest.approx((60.0, 10.0 / math.sqrt(3)))  # 50, 70, 60 %
    assert col.completion_pct == pytest.approx((95.0, 5.0 / math.sqrt(3)))  # 90, 95, 100 %
    assert col.samples == pytest.approx((1200.0, 200.0 / math.sqrt(3)))
    table = markdown(cells)
    assert "| 20 | Demo | 3 | 60.00 ± 5.77 | 76.25 ± 2.72 | 2200.0 ± 115.5 | ≈ 2531 (implied) |" in table
    assert "| 20 | CoL | 3 | 95.00 ± 2.89 | 90.25 ± 5.63 | 1200.0 ± 115.5 | 1574.5 ± 54.2 |" in table
    assert "| 20 | +35.00 | +14.00 | 45.45 | 37.79 |" in table
    report = write_report(rs, tmp_path)
    assert report.read_text().count("|") > 20
    for png in ("completion.png", "samples.png"):
        assert (tmp_path / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.e2e
def test_one_tiny_trial_on_the_lockstep_sitl(tmp_path: Path) -> None:
    """1 participant, CoL over 2 interactions, final policy flown on 2 held-out starts."""
    setup = quick_setup(participants=("P1",), conditions=("col",), interactions=(2,), eval_runs=2)
    trial = Trial("P1", "col", 2, 0)
    r = run_trial(setup, trial, tmp_path)
    assert r.status == "ok" and r.eval_runs == 2
    trial_dir = tmp_path / "trials" / trial.key
    rows = (trial_dir / "train" / "human.csv").read_text().splitlines()
    assert r.human_samples == len(rows) - 1 > 0  # every recorded sample, header aside
    train = [json.loads(line) for line in (trial_dir / "train" / "episodes.jsonl").read_text().splitlines()]
    assert [e["phase"] for e in train] == ["demonstration", "intervention"]
    assert [e["seed"] for e in train] == [0, 1]
    assert all(e["loss_all"] is not None for e in train)  # the fit is logged after every episode
    evals = [json.loads(line) for line in (trial_dir / "eval_episodes.jsonl").read_text().splitlines()]
    assert [e["seed"] for e in evals] == [100_000, 100_001] and all(e["human_samples"] == 0 for e in evals)
    # the result counts what the evaluation flights record (0 <= k <= 2 could not fail)
    assert r.eval_successes == sum(e["success"] is True for e in evals)
    assert (tmp_path / r.final_checkpoint).exists()
    assert [p.name for p in trial_dir.iterdir() if p.name.startswith("tmp")] == []  # evaluation scratch removed


@pytest.mark.e2e
def test_a_col_plus_trial_is_col_with_the_supported_switches(tmp_path: Path) -> None:
    """The same cell as CoL, its demonstrations flown with DART's noise: other states, so other
    samples, on the same schedule; the switch comes from the condition, not the config."""
    setup = quick_setup(participants=("P1",), conditions=("col", "colplus"), interactions=(2,), eval_runs=1)
    assert setup.companion.learner.demo_noise_std == 0.0
    col = run_trial(setup, Trial("P1", "col", 2, 0), tmp_path)
    plus = run_trial(setup, Trial("P1", "colplus", 2, 0), tmp_path)
    assert col.status == plus.status == "ok"
    train = tmp_path / "trials" / "P1-colplus-02-s0" / "train"
    assert [json.loads(line)["phase"] for line in (train / "episodes.jsonl").read_text().splitlines()] == [
        "demonstration", "intervention"]
    col_rows = (tmp_path / "trials" / "P1-col-02-s0" / "train" / "human.csv").read_text().splitlines()
    plus_rows = (train / "human.csv").read_text().splitlines()
    assert col_rows[:2] == plus_rows[:2] and col_rows != plus_rows  # the same first sample, then a perturbed flight


def _evaluation(path: Path) -> list[dict[str, object]]:
    """Evaluation records without their wall times (the only field that may differ)."""
    return [{k: v for k, v in json.loads(line).items() if k != "wall_time_s"}
            for line in path.read_text().splitlines()]


@pytest.mark.e2e
def test_a_prefix_checkpoint_evaluates_like_a_trial_trained_to_that_count_alone(tmp_path: Path) -> None:
    """Int@1 read from a 2-episode run is the same policy, flying the same evaluation, as Int@1
    trained alone: same weights, same human samples, the same evaluation records."""
    setup = quick_setup(participants=("P2",), conditions=("int",), interactions=(1, 2), eval_runs=2)
    (run,) = plan(setup.exp)
    assert run.evaluated_at == (1, 2)
    prefix_1, _ = run_training(setup, run, tmp_path / "prefix")
    alone = run_trial(setup, Trial("P2", "int", 1, 0), tmp_path / "alone")
    keep = ("eval_runs", "eval_successes", "human_samples", "interventions", "intervened_steps")
    assert [getattr(prefix_1, k) for k in keep] == [getattr(alone, k) for k in keep]
    a, _ = load_checkpoint(tmp_path / "prefix" / prefix_1.final_checkpoint)
    b, _ = load_checkpoint(tmp_path / "alone" / alone.final_checkpoint)
    assert a.version == b.version and all(np.array_equal(x, y) for x, y in zip(a.weights, b.weights))
    key = "trials/P2-int-01-s0/eval_episodes.jsonl"
    assert _evaluation(tmp_path / "prefix" / key) == _evaluation(tmp_path / "alone" / key)
    assert prefix_1.final_checkpoint == "trials/P2-int-02-s0/train/checkpoints/episode_000.npz"


def quick_setup(**grid: object) -> ExperimentSetup:
    """The quick experiment file's companion and SITL settings (load-proof waits), this grid."""
    setup = load_experiment(REPO / "configs" / "experiment_quick.toml")
    return dataclasses.replace(setup, exp=ExperimentConfig(**grid))  # type: ignore[arg-type]


@pytest.mark.slow
def test_a_trial_is_a_pure_function_of_its_config(tmp_path: Path) -> None:
    """Two runs of one cell at the same time (competing for the cores) write the same bytes."""
    setup = quick_setup(participants=("P3",), conditions=("col",), interactions=(2,), eval_runs=3)
    trial = Trial("P3", "col", 2, 0)
    with ThreadPoolExecutor(2) as pool:  # each run_trial drives its own SITL process
        a, b = pool.map(lambda d: run_trial(setup, trial, tmp_path / d), ("a", "b"))
    keep = ("eval_successes", "human_samples", "interventions", "train_successes", "final_checkpoint")
    assert [getattr(a, k) for k in keep] == [getattr(b, k) for k in keep]
    csv = "trials/P3-col-02-s0/train/human.csv"
    assert (tmp_path / "a" / csv).read_bytes() == (tmp_path / "b" / csv).read_bytes()


@pytest.mark.slow
def test_col_experiment_quick_then_resume(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from companion.cli import app

    monkeypatch.chdir(REPO)
    out = tmp_path / "quick"
    first = CliRunner().invoke(app, ["experiment", "--quick", "--workers", "2", "--out", str(out)])
    assert first.exit_code == 0, first.output
    assert json.loads(first.output.strip().splitlines()[-1])["trials"] == 2
    assert (out / "report.md").exists() and (out / "completion.png").exists()
    lines = (out / "results.jsonl").read_text()
    again = CliRunner().invoke(app, ["experiment", "--quick", "--out", str(out)])
    assert again.exit_code == 0 and (out / "results.jsonl").read_text() == lines  # nothing redone


@pytest.mark.slow
@pytest.mark.timeout(8 * 3600)
def test_the_full_paper_grid(tmp_path: Path) -> None:
    """48 trials of 100 evaluation runs: hours on 2 cores (docs/experiment.md)."""
    setup = load_experiment(REPO / "configs" / "experiment.toml")
    results = run_grid(setup, tmp_path, workers=2, progress=False)
    assert len(results) == 48
    assert "| 20 | CoL |" in write_report(results, tmp_path).read_text()


@pytest.mark.e2e
def test_verify_reruns_committed_trials_and_catches_a_changed_line(tmp_path: Path) -> None:
    """A 2-trial grid (Demo@1 read from a 2-episode run, Demo@2), then `--verify`: each rerun
    writes its committed line byte for byte; a line edited by hand is caught."""
    from companion.cli import app

    config = tmp_path / "tiny.toml"
    quick = (REPO / "configs" / "experiment_quick.toml").read_text()
    config.write_text(quick.replace('conditions = ["demo", "col"]', 'conditions = ["demo"]')
                      .replace("interactions = [2]", "interactions = [1, 2]").replace("eval_runs = 3", "eval_runs = 2"))
    out = tmp_path / "grid"
    made = CliRunner().invoke(app, ["experiment", "--config", str(config), "--workers", "1", "--out", str(out)])
    assert made.exit_code == 0, made.output
    assert (out / "config.toml").read_text() == config.read_text()
    assert len((out / "timings.jsonl").read_text().splitlines()) == 2
    assert "wall_s" not in (out / "results.jsonl").read_text()
    ok = CliRunner().invoke(app, ["experiment", "--verify", str(out), "--trials", "2"])
    assert ok.exit_code == 0, ok.output
    assert json.loads(ok.output.strip().splitlines()[-1])["identical"] == 2
    lines = (out / "results.jsonl").read_text().splitlines()
    tampered = [line.replace('"eval_successes": ', '"eval_successes": 1 + ', 1) for line in lines]
    tampered = [json.dumps({**json.loads(line.replace("1 + ", "")), "human_samples": 1}) for line in tampered]
    (out / "results.jsonl").write_text("\n".join(tampered) + "\n")
    bad = CliRunner().invoke(app, ["experiment", "--verify", str(out), "--trials", "1", "--seed", "0"])
    assert bad.exit_code == 1 and "DIFFERS" in bad.output and "human_samples" in bad.output
