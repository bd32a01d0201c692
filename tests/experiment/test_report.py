"""The experiment report's paired tables, per-sample figures, per-participant table and plots,
on hand-made results whose numbers are worked out by hand."""

from __future__ import annotations

from pathlib import Path

import pytest

from companion.experiment.grid import Trial
from companion.experiment.report import (
    curve,
    efficiency_markdown,
    paired_comparisons,
    paired_markdown,
    participants_markdown,
    write_report,
)
from companion.experiment.results import TrialResult

PNG = b"\x89PNG\r\n\x1a\n"


def result(participant: str, condition: str, interactions: int, seed: int, successes: int,
           samples: int, status: str = "ok") -> TrialResult:
    """100 evaluation runs, so ``successes`` is the completion in percent."""
    return TrialResult(trial=Trial(participant, condition, interactions, seed),  # type: ignore[arg-type]
                       fingerprint="x", status=status,  # type: ignore[arg-type]
                       eval_runs=100, eval_successes=successes, human_samples=samples)


def grid() -> list[TrialResult]:
    """At 20: four participants, seed 0, all three conditions.
    CoL - Demo = 10, 20, 30, 40 (mean 25); CoL - Int = 20, 15, 40, 35 (mean 27.5).
    Means: Int 52.5 % with 1050 samples, Demo 55 % with 2150, CoL 80 % with 1350.
    At 8: P1 and P2 with Demo and CoL (differences 5 and -5), P3's CoL alone (no partner)."""
    rows = (("P1", 60, 2000, 70, 1200, 50, 900), ("P2", 50, 2100, 70, 1300, 55, 1000),
            ("P3", 70, 2200, 100, 1400, 60, 1100), ("P4", 40, 2300, 80, 1500, 45, 1200))
    rs = []
    for p, demo, demo_n, col, col_n, int_, int_n in rows:
        rs += [result(p, "demo", 20, 0, demo, demo_n), result(p, "col", 20, 0, col, col_n),
               result(p, "int", 20, 0, int_, int_n)]
    rs += [result("P1", "demo", 8, 0, 40, 800), result("P1", "col", 8, 0, 45, 500),
           result("P2", "demo", 8, 0, 50, 800), result("P2", "col", 8, 0, 45, 500),
           result("P3", "col", 8, 0, 90, 500),
           result("P4", "demo", 8, 0, 0, 0, status="error"), result("P4", "col", 8, 0, 60, 500)]
    return rs


def test_paired_comparisons_per_count() -> None:
    found = {(c.interactions, c.b): c for c in paired_comparisons(grid())}
    assert set(found) == {(8, "demo"), (20, "demo"), (20, "int")}  # no Int at 8: no row
    assert found[(20, "demo")].differences == (10.0, 20.0, 30.0, 40.0)
    assert found[(20, "int")].mean == 27.5
    assert found[(8, "demo")].differences == (5.0, -5.0)  # P3 and P4 have no Demo partner


def test_paired_table_rows(tmp_path: Path) -> None:
    table = "\n".join(paired_markdown(grid()))
    ci = paired_comparisons(grid())[1].ci  # 20, CoL - Demo
    assert ci is not None
    assert (f"| 20 | CoL − Demo | 4 | +25.00 | [{ci[0]:+.2f}, {ci[1]:+.2f}] | 0.125 | 0.125 | 4 / 0 / 0 | +14.00 |"
            in table)
    assert "| 20 | CoL − Int | 4 | +27.50 |" in table and "| 0.125 | 0.125 | 4 / 0 / 0 |  |" in table
    # two pairs, +5 and -5: mean 0, interval and both tests say nothing (p = 1)
    assert "| 8 | CoL − Demo | 2 | +0.00 | [-5.00, +5.00] | 1.000 | 1.000 | 1 / 0 / 1 | +20.75 |" in table
    assert "BCa" in table and "primary" in table and "zsplit" in table
    assert paired_markdown([r for r in grid() if r.trial.condition == "col"]) == []


def test_completion_per_1000_samples_table() -> None:
    table = "\n".join(efficiency_markdown(grid()))
    # Int 52.5 / 1050, Demo 55 / 2150, CoL 80 / 1350 (x 1000); CoL / Demo = 59.26 / 25.58
    # paper at 20: 90.25 / 1574.5 and 76.25 / 2530.9 (x 1000), ratio 1.90
    assert "| 20 | 50.00 | 25.58 | 59.26 | 2.32× | 57.32 / 30.13 | 1.90× |" in table
    # at 8: Demo 45 / 800 (P4's failed trial left out), CoL 60 / 500
    assert "| 8 |  | 56.25 | 120.00 | 2.13× |  |  |" in table
    assert "1.84×" in table


def test_per_participant_table() -> None:
    rs = grid() + [result("P1", "col", 20, 1, 90, 1000)]  # a second replicate for P1's CoL
    table = "\n".join(participants_markdown(rs))
    assert "| P1 | 20 | 2 | 50.00 (1 of 2 seeds) | 900 | 60.00 (1 of 2 seeds) | 2000 | 80.00 | 1100 |" in table
    assert "| P3 | 8 | 1 |  |  |  |  | 90.00 | 500 |" in table
    assert "| P4 | 8 | 1 |  |  |  |  | 60.00 | 500 |" in table  # the failed Demo is not shown


def test_learning_curve_points_with_t_interval() -> None:
    points = curve(grid(), "col", "completion")
    assert [(p.interactions, p.mean) for p in points] == [(8, 60.0), (20, 80.0)]
    # at 20: 70, 70, 100, 80: s.d. 14.142, s.e. 7.071, t(0.975, 3) = 3.1824
    assert points[1].band == pytest.approx((80.0 - 22.503, 80.0 + 22.503), abs=1e-3)
    assert [p.mean for p in curve(grid(), "demo", "samples")] == [800.0, 2150.0]


def test_write_report_writes_the_tables_and_every_plot(tmp_path: Path) -> None:
    path = write_report(grid(), tmp_path)
    text = path.read_text()
    assert path == tmp_path / "report.md"
    for heading in ("## Paired comparisons", "## Task completion per 1,000 human samples",
                    "## Per participant"):
        assert heading in text
    assert "| 20 | CoL − Demo | 4 | +25.00 |" in text
    for png in ("completion.png", "samples.png", "learning_curve.png", "samples_curve.png"):
        data = (tmp_path / png).read_bytes()
        assert data[:8] == PNG and len(data) > 1000
        assert f"]({png})" in text


def test_a_report_of_nothing_finished_has_no_tables_or_plots(tmp_path: Path) -> None:
    text = write_report([result("P1", "col", 4, 0, 0, 0, status="error")], tmp_path).read_text()
    assert "## Paired comparisons" not in text and "## Per participant" not in text
    assert not (tmp_path / "learning_curve.png").exists()


def test_one_rule_for_every_reader_an_error_line_never_hides_an_ok_one(tmp_path: Path) -> None:
    """ok then error (a retry that failed), error then ok, two oks: the report, the statistics
    and the results file agree on which line counts."""
    from companion.experiment.report import latest_ok, summarise
    from companion.experiment.results import ResultsFile
    from companion.statistics import counted, finished

    lines = [result("P1", "col", 20, 0, 70, 1000), result("P1", "col", 20, 0, 0, 0, status="error"),
             result("P2", "col", 20, 0, 0, 0, status="error"), result("P2", "col", 20, 0, 90, 1100),
             result("P3", "col", 20, 0, 10, 900), result("P3", "col", 20, 0, 30, 900),
             result("P4", "col", 20, 0, 0, 0, status="error")]
    path = tmp_path / "results.jsonl"
    for r in lines:
        ResultsFile(path).append(r)
    loaded = ResultsFile(path).load()
    want = {"P1": 70.0, "P2": 90.0, "P3": 30.0}
    for rows in (counted(loaded), latest_ok(loaded), finished(loaded, "col", 20)):
        assert {r.trial.participant: r.completion_pct for r in rows} == want
    (cell,) = summarise(loaded)
    assert cell.n == 3 and cell.completion_pct[0] == pytest.approx(190 / 3)
    assert set(ResultsFile(path).finished("x")) == {"P1-col-20-s0", "P2-col-20-s0", "P3-col-20-s0"}


def test_variants_show_each_runs_endpoints_their_spread_and_how_far_trials_moved(tmp_path: Path) -> None:
    from companion.experiment.report import read_variants, variants_markdown
    from companion.experiment.results import ResultsFile

    primary = grid()
    # the variant: P1's CoL@20 moved from 70 to 90 (CoL - Demo at 20: 30, 20, 30, 40 -> mean 30)
    variant = [result("P1", "col", 20, 0, 90, 1200) if (r.trial.participant, r.trial.condition,
               r.trial.interactions) == ("P1", "col", 20) else r for r in primary]
    folder = tmp_path / "variants" / "other-kernel"
    for r in variant:
        ResultsFile(folder / "results.jsonl").append(r)
    variants = read_variants(tmp_path)
    assert list(variants) == ["other-kernel"]
    text = "\n".join(variants_markdown(primary, variants, "pinned"))
    row = next(line for line in text.splitlines() if line.startswith("| CoL − Demo at 20 (primary)"))
    assert "| +25.00 [" in row and "| +30.00 [" in row and "| 5.00 |" in row
    agreement = next(line for line in text.splitlines() if line.startswith("| pinned vs other-kernel"))
    # 18 trials counted in both (P4's Demo@8 is an error line), 17 identical, one moved 20 points
    assert agreement == "| pinned vs other-kernel | 18 | 17 | 1.11 | 20.00 |"
    assert variants_markdown(primary, {}) == []
    report = write_report(primary, tmp_path).read_text()
    assert "## Numeric variants" in report and "other-kernel" in report
