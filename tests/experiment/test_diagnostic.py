"""The take-over diagnostic on run folders written here: which episodes it reads, and its figures."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from companion.experiment.diagnostic import diagnose, early_episodes


def record(episode: int, phase: str, success: bool, interventions: int, samples: int, loss: float | None) -> dict:
    return {"episode": episode, "phase": phase, "success": success, "interventions": interventions,
            "human_samples": samples, "loss_intervention": loss}


def write_run(root: Path, key: str, records: list[dict]) -> None:
    folder = root / "trials" / key / "train"
    folder.mkdir(parents=True)
    (folder / "episodes.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))


def test_the_diagnostic_reads_the_first_intervention_episodes_of_finished_runs(tmp_path: Path) -> None:
    int_run = [record(0, "intervention", False, 0, 0, None), record(1, "intervention", False, 2, 40, 0.4),
               record(2, "intervention", True, 1, 10, 0.2), record(3, "intervention", True, 0, 0, 0.2)]
    int_run += [record(i, "intervention", True, 0, 0, 0.1) for i in range(4, 20)]
    col_run = [record(i, "demonstration", True, 0, 100, None) for i in range(10)]
    col_run += [record(10, "intervention", True, 1, 30, 0.3), record(11, "intervention", False, 0, 0, 0.3)]
    col_run += [record(i, "intervention", True, 0, 0, 0.3) for i in range(12, 20)]
    write_run(tmp_path, "P1-int-20-s0", int_run)
    write_run(tmp_path, "P1-col-20-s0", col_run)
    write_run(tmp_path, "P2-int-20-s0", int_run[:7])  # unfinished: not counted

    assert [r["episode"] for r in early_episodes(col_run, "col")] == [10, 11]
    out = diagnose(tmp_path)
    i = out["int"]["runs"]["P1-int-20-s0"]
    assert i["failed_share"] == 0.5 and i["failed_without_takeover_share"] == 0.25
    assert i["interventions_per_episode"] == 0.75 and i["intervened_steps_per_episode"] == 12.5
    assert i["loss_intervention"] == [None, 0.4, 0.2, 0.2]
    assert list(out["int"]["runs"]) == ["P1-int-20-s0"] and out["int"]["mean"]["runs"] == 1
    c = out["col"]["mean"]
    assert c["failed_share"] == 0.5 and c["failed_without_takeover_share"] == 0.5
    assert c["loss_intervention_after_episode"] == [pytest.approx(0.3), pytest.approx(0.3)]
