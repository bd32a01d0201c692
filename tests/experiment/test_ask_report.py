"""The ask condition in the experiment: its trials, result lines and report section."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from companion.app import asking_config, phases_for
from companion.config import CompanionConfig
from companion.control.arbiter import Phase
from companion.errors import ConfigError
from companion.experiment.ask_report import ask_markdown, reductions
from companion.experiment.grid import ExperimentConfig, Trial, load_experiment
from companion.experiment.report import paired_comparisons, write_report
from companion.experiment.results import TrialResult

REPO = Path(__file__).resolve().parents[2]


def _result(p: str, cond: str, seed: int, successes: int, watched: int | None, steps: int = 2000,
            supervised: int | None = None) -> TrialResult:
    return TrialResult(Trial(p, cond, 20, seed), "f", "ok", eval_runs=50, eval_successes=successes,  # type: ignore[arg-type]
                       human_samples=1500, requests=None if watched is None else 7, watched_steps=watched,
                       supervised_steps=supervised if supervised is not None else (None if watched is None else 2000 + watched),
                       intervention_phase_steps=None if watched is None else steps)


def test_the_ask_schedule_is_cols_and_needs_an_ensemble() -> None:
    assert phases_for("ask", 20) == phases_for("col", 20)
    assert phases_for("ask", 4) == [Phase.DEMONSTRATION] * 2 + [Phase.INTERVENTION] * 2
    with pytest.raises(ConfigError, match="ensemble_members"):
        asking_config(CompanionConfig(), "ask")
    learner = CompanionConfig().learner.model_copy(update={"ensemble_members": 3})
    cfg = asking_config(CompanionConfig().model_copy(update={"learner": learner}), "ask")
    assert cfg.ask.enabled and not asking_config(cfg.model_copy(update={"ask": CompanionConfig().ask}), "col").ask.enabled
    assert ExperimentConfig().conditions == ("demo", "int", "col")  # the paper's grid stays the default


def test_the_ask_experiment_file_loads_and_refuses_a_single_network(tmp_path: Path) -> None:
    setup = load_experiment(REPO / "configs" / "ask.toml")
    assert setup.exp.conditions == ("col", "ask") and setup.companion.learner.ensemble_members == 5
    bad = tmp_path / "bad.toml"
    bad.write_text('[experiment]\nconditions = ["col", "ask"]\n')
    with pytest.raises(ConfigError, match="ensemble"):
        load_experiment(bad)


def test_supervision_fields_are_written_only_when_set() -> None:
    plain = _result("P1", "col", 0, 40, None)
    assert "watched_steps" not in plain.to_json_dict() and "requests" not in plain.to_json_dict()
    asked = _result("P1", "ask", 0, 40, 300)
    line = json.loads(asked.to_json_line())
    assert line["watched_steps"] == 300 and line["requests"] == 7
    assert TrialResult.from_json_dict(line) == TrialResult.from_json_dict(json.loads(asked.to_json_line()))
    assert TrialResult.from_json_dict(json.loads(plain.to_json_line())).watched_steps is None


def test_the_report_compares_ask_with_col_pair_by_pair(tmp_path: Path) -> None:
    results = []
    for i, p in enumerate(("P1", "P2", "P3", "P4")):
        for seed in (0, 1):
            results.append(_result(p, "col", seed, 40 + i, 2000))
            results.append(_result(p, "ask", seed, 38 + i + seed, 500 + 100 * seed))
    watched = reductions(results, 20, "watched_steps")
    assert len(watched) == 8 and watched[0] == pytest.approx(75.0) and watched[1] == pytest.approx(70.0)
    text = "\n".join(ask_markdown(results))
    assert "| 20 | 8 | 72.5 |" in text and "| 20 | Ask | 8 |" in text
    comparison = next(c for c in paired_comparisons(results) if (c.a, c.b) == ("ask", "col"))
    assert comparison.n == 8 and comparison.mean == pytest.approx(-3.0)  # -4 and -2 points, alternately
    report = write_report(results, tmp_path).read_text()
    assert "Asking for help: supervision" in report and "Ask − CoL" in report
    assert ask_markdown([r for r in results if r.trial.condition == "col"]) == []


def test_the_trace_plot_picks_the_first_intervention_episode_with_a_request(tmp_path: Path) -> None:
    from companion.experiment.ask_report import plot_ask_trace

    trace = tmp_path / "train" / "ask_trace.jsonl"
    trace.parent.mkdir()
    lines = [{"episode": 0, "phase": "demonstration", "threshold": None, "step": [0, 1], "score": [None, None],
              "who": ["human", "human"]},
             {"episode": 1, "phase": "intervention", "threshold": 0.01, "step": [0, 1, 2], "score": [0.001, 0.02, 0.005],
              "who": ["policy", "hold", "human"]}]
    trace.write_text("".join(json.dumps(line) + "\n" for line in lines))
    got = plot_ask_trace(trace, None, tmp_path / "trace.png")
    assert got["episode"] == 1 and got["who"] == {"policy": 1, "human": 1, "hold": 1, "land": 0}
    assert (tmp_path / "trace.png").stat().st_size > 1000
    with pytest.raises(ValueError):
        plot_ask_trace(trace, 7, tmp_path / "none.png")
