"""bench/ab.py's summary: which figures it compares and how (it decides what a before/after
bench run is said to show)."""

from __future__ import annotations

from pathlib import Path

import pytest

from colcommon.script_module import load_script

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def ab():
    return load_script(ROOT / "bench" / "ab.py", "bench_ab")


def test_only_rates_and_costs_are_compared_by_their_dotted_path(ab) -> None:
    line = {"bench": "x", "eval_cpu_ms_per_step": 2.0, "eval_episodes": 40, "ok": True,
            "lanes": {"cpu_ms_per_step": {"1": 1.5}, "episodes": 20}}
    assert ab.figures(line) == {"eval_cpu_ms_per_step": 2.0, "lanes.cpu_ms_per_step.1": 1.5}


def test_the_paired_ratio_is_the_median_of_the_rounds_own_ratios(ab) -> None:
    """A machine that drifts between rounds moves both runs of a round: the side medians see a
    change of 9 % where each round's own ratio is 1.0 or near it."""
    before = [{"cpu_ms_per_step": v} for v in (1.0, 1.0, 1.5, 1.5, 1.5)]
    after = [{"cpu_ms_per_step": v} for v in (1.0, 1.02, 1.5, 1.5, 1.4)]
    row = ab.summary(before, after)["cpu_ms_per_step"]
    assert row["before"] == 1.5 and row["after"] == 1.4
    assert row["after_over_before"] == pytest.approx(0.9333, abs=1e-4)
    assert row["paired_after_over_before"] == 1.0


def test_kept_lines_come_back_in_round_order_and_a_missing_side_is_refused(ab, tmp_path: Path) -> None:
    for side, values in (("before", (1.0, 2.0, 3.0)), ("after", (1.1, 2.1, 3.1))):
        for i, v in enumerate(values, start=1):
            (tmp_path / f"{side}-experiment_speed-{i}.json").write_text(f'progress\n{{"cpu_ms_per_step": {v}}}\n')
    (tmp_path / "after-experiment_speed-10.json").write_text('{"cpu_ms_per_step": 9.0}\n')
    with pytest.raises(SystemExit, match="3 before and 4 after"):
        ab.kept_lines(tmp_path, "experiment_speed.py")
    (tmp_path / "before-experiment_speed-10.json").write_text('{"cpu_ms_per_step": 8.0}\n')
    lines = ab.kept_lines(tmp_path, "experiment_speed.py")
    assert [x["cpu_ms_per_step"] for x in lines["before"]] == [1.0, 2.0, 3.0, 8.0]
    assert [x["cpu_ms_per_step"] for x in lines["after"]] == [1.1, 2.1, 3.1, 9.0]
