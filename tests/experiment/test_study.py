"""col study's protocol and folder without a vehicle: the counterbalanced orders, the blocks,
what is done read back from the files, the questionnaire, and what Start may fly."""

from __future__ import annotations

import itertools
import json
from collections import Counter
from pathlib import Path

import pytest

from companion.console.study import PRACTICE_START_SEED, ConsoleStudy
from companion.errors import ConfigError
from companion.experiment.grid import ExperimentSetup, load_experiment
from companion.experiment.results import TrialResult
from companion.experiment.study import (
    CONDITION_ORDERS,
    CONDITION_ORDERS_WITH_COL_PLUS,
    TLX_SCALES,
    StudyFolder,
    StudyPlan,
    check_answers,
    condition_order,
)

PAPER = Path(__file__).resolve().parents[2] / "configs" / "paper.toml"
ANSWERS = {"mental": 70, "physical": 20, "temporal": 55, "performance": 30, "effort": 65, "frustration": 40}


def test_the_orders_are_a_williams_design_for_three_conditions() -> None:
    assert sorted(CONDITION_ORDERS) == sorted(itertools.permutations(("demo", "int", "col")))
    for position in range(3):  # each condition in each position twice
        assert Counter(o[position] for o in CONDITION_ORDERS) == {"demo": 2, "int": 2, "col": 2}
    follows = Counter((o[i], o[i + 1]) for o in CONDITION_ORDERS for i in range(2))
    assert set(follows.values()) == {2} and len(follows) == 6  # each after each other one, twice
    assert condition_order("S01") == CONDITION_ORDERS[0] and condition_order("S07") == CONDITION_ORDERS[0]
    assert condition_order("S02") == CONDITION_ORDERS[1]


def test_with_col_plus_the_orders_are_a_williams_square_for_four_conditions() -> None:
    four = ("demo", "int", "col", "colplus")
    assert all(sorted(o) == sorted(four) for o in CONDITION_ORDERS_WITH_COL_PLUS)
    for position in range(4):  # each condition once in each position
        assert Counter(o[position] for o in CONDITION_ORDERS_WITH_COL_PLUS) == dict.fromkeys(four, 1)
    follows = Counter((o[i], o[i + 1]) for o in CONDITION_ORDERS_WITH_COL_PLUS for i in range(3))
    assert follows == {pair: 1 for pair in itertools.permutations(four, 2)}  # each right after each other once
    assert condition_order("S05", col_plus=True) == CONDITION_ORDERS_WITH_COL_PLUS[0]
    blocks = StudyPlan("S02", 8, 0, col_plus=True).blocks()
    assert [b.name for b in blocks] == ["S02-int-08-s0", "S02-col-08-s0", "S02-demo-08-s0", "S02-colplus-08-s0"]


def test_a_plan_written_before_col_plus_resumes(tmp_path: Path) -> None:
    folder = StudyFolder(tmp_path / "s01", StudyPlan("S01", 4, 1)).open()
    plan = json.loads((folder.root / "study.json").read_text())
    del plan["col_plus"]
    (folder.root / "study.json").write_text(json.dumps(plan))
    StudyFolder(tmp_path / "s01", StudyPlan("S01", 4, 1)).open()  # three conditions, as it was written
    with pytest.raises(ConfigError, match="another study plan"):
        StudyFolder(tmp_path / "s01", StudyPlan("S01", 4, 1, col_plus=True)).open()


@pytest.mark.parametrize("bad", [{"participant": "S00"}, {"participant": "P1"}, {"participant": "s01"},
                                 {"interactions": 0}, {"practice_episodes": 21}, {"seed": -1}])
def test_a_bad_plan_is_refused(bad: dict) -> None:
    with pytest.raises(ConfigError):
        StudyPlan(**{"participant": "S01", "interactions": 4, "practice_episodes": 1, **bad})


def test_the_blocks_are_practice_then_the_participants_order_as_grid_trials() -> None:
    plan = StudyPlan("S02", 8, 2, seed=1)
    blocks = plan.blocks()
    assert [b.name for b in blocks] == ["practice", "S02-int-08-s1", "S02-col-08-s1", "S02-demo-08-s1"]
    assert blocks[0].condition == "demo" and blocks[0].episodes == 2 and blocks[0].trial is None
    assert blocks[2].trial is not None and blocks[2].trial.start_seed == 1000
    assert [b.name for b in StudyPlan("S02", 8, 0).blocks()][0] == "S02-int-08-s0"  # no practice


@pytest.mark.parametrize("answers,why", [({**ANSWERS, "mental": 101}, "0 to 100"), ({**ANSWERS, "effort": 5.5}, "whole"),
                                         ({**ANSWERS, "effort": True}, "whole"), ({"mental": 1}, "exactly"),
                                         ([1, 2], "exactly"), ({**ANSWERS, "mood": 3}, "exactly")])
def test_questionnaire_answers_are_checked(answers: object, why: str) -> None:
    with pytest.raises(ConfigError, match=why):
        check_answers(answers)
    assert check_answers(dict(ANSWERS)) == ANSWERS and set(ANSWERS) == set(TLX_SCALES)


def _flown(folder: StudyFolder, block_index: int, episodes: int) -> None:
    block = folder.plan.blocks()[block_index]
    run = folder.run_dir(block)
    run.mkdir(parents=True, exist_ok=True)
    with (run / "episodes.jsonl").open("a") as f:
        for i in range(episodes):
            f.write(json.dumps({"episode": i}) + "\n")


def _finished(folder: StudyFolder, block_index: int, setup: ExperimentSetup) -> None:
    trial = folder.plan.blocks()[block_index].trial
    assert trial is not None
    folder.add_result(TrialResult(trial, setup.fingerprint(), "ok", eval_runs=2, eval_successes=1))


def test_the_folder_knows_what_is_done_from_its_files_and_asks_for_each_questionnaire(tmp_path: Path) -> None:
    setup = load_experiment(PAPER)
    plan = StudyPlan("S01", 2, 1)
    folder = StudyFolder(tmp_path / "s01", plan).open()
    study = ConsoleStudy(folder, setup)
    with pytest.raises(ConfigError, match="practice: demo with 1 episodes"):
        study.check_start("col", 2)
    practice = study.check_start("demo", 1)
    assert study.seed(practice) == PRACTICE_START_SEED and folder.run_dir(practice) == tmp_path / "s01" / "practice"
    _flown(folder, 0, 1)
    first = folder.next_block()
    assert first is not None and first.name == "S01-demo-02-s0"
    _flown(folder, 1, 1)  # a block stopped after one episode: Start resumes it with the rest
    with pytest.raises(ConfigError, match="S01-demo-02-s0: demo with 1 episodes"):
        study.check_start("demo", 2)
    assert study.check_start("demo", 1) == first and study.seed(first) == 0
    assert study.after_run(first) is None  # not all flown yet: no trial
    _flown(folder, 1, 1)
    _finished(folder, 1, setup)
    assert folder.questionnaire_due() == "S01-demo-02-s0"
    with pytest.raises(ConfigError, match="questionnaire"):
        study.check_start("int", 2)
    line = study.answer(dict(ANSWERS))
    assert line["raw_tlx"] == round(sum(ANSWERS.values()) / 6, 2) and not line["skipped"]
    with pytest.raises(ConfigError, match="no questionnaire is due"):
        study.answer(None)
    _flown(folder, 2, 2)
    _finished(folder, 2, setup)
    assert study.answer(None)["skipped"]
    status = study.status()
    assert [b["state"] for b in status["blocks"]] == ["done", "done", "done", "next"]
    assert status["next"] == {"name": "S01-col-02-s0", "condition": "col", "episodes": 2}
    assert status["eval_runs"] == 100 and status["questionnaire_for"] is None

    again = StudyFolder(tmp_path / "s01", plan).open()  # reopened: the same state
    assert again.next_block() == folder.next_block() and again.answered() == {"S01-demo-02-s0", "S01-int-02-s0"}
    with pytest.raises(ConfigError, match="another study plan"):
        StudyFolder(tmp_path / "s01", StudyPlan("S01", 4, 1)).open()
    lines = [json.loads(x) for x in (tmp_path / "s01" / "results.jsonl").read_text().splitlines()]
    assert [x["trial"]["key"] for x in lines] == ["S01-demo-02-s0", "S01-int-02-s0"]


def test_a_finished_blocks_episodes_cannot_be_discarded(tmp_path: Path) -> None:
    """Its policy was evaluated on what it learned: the trial line stands as written."""
    from companion.config import CompanionConfig
    from companion.console.session import ConsoleOptions, ConsoleSession

    setup = load_experiment(PAPER)
    folder = StudyFolder(tmp_path / "s01", StudyPlan("S01", 2, 0)).open()
    study = ConsoleStudy(folder, setup)
    session = ConsoleSession(CompanionConfig(), ConsoleOptions(run_dir=tmp_path / "s01" / "practice"),
                             lambda m: None, lambda f: None, study)
    block = study.check_start("demo", 2)
    _flown(folder, 0, 2)
    session.records.append({"episode": 1, "discarded": None})
    assert not study.trial_written()
    _finished(folder, 0, setup)
    assert study.trial_written() and block.trial is not None
    with pytest.raises(ConfigError, match="trial written"):
        session.discard_last("oops")
