"""Paired statistics of the experiment's report, against values computed by hand."""

from __future__ import annotations

import math

import pytest

from companion.experiment.grid import Trial
from companion.experiment.results import TrialResult
from companion.statistics import (
    MONTE_CARLO_SIGN_FLIPS,
    bootstrap_mean_ci,
    compare_paired,
    completion_per_1000_samples,
    paired_differences,
    paired_test,
    paired_values,
    sign_flip_pvalue,
    t_interval,
    wilcoxon_pvalue,
    wilson_interval,
)


def result(participant: str, condition: str, interactions: int, seed: int, successes: int,
           samples: int = 1000, status: str = "ok") -> TrialResult:
    """100 evaluation runs, so ``successes`` is the completion in percent."""
    return TrialResult(trial=Trial(participant, condition, interactions, seed),  # type: ignore[arg-type]
                       fingerprint="x", status=status,  # type: ignore[arg-type]
                       eval_runs=100, eval_successes=successes, human_samples=samples)


def four_pairs() -> list[TrialResult]:
    """CoL beats Demo at 20 by 10, 20, 30, 40 points (P1..P4, seed 0), plus noise to ignore."""
    rs = [result("P1", "col", 20, 0, 5)]  # an earlier line for P1's CoL: the later one wins
    for p, demo, col in (("P1", 50, 60), ("P2", 60, 80), ("P3", 40, 70), ("P4", 55, 95)):
        rs += [result(p, "demo", 20, 0, demo), result(p, "col", 20, 0, col)]
    rs.append(result("P1", "col", 20, 1, 90))  # seed 1: no Demo partner
    rs.append(result("P2", "demo", 8, 0, 10))  # another count, no CoL partner there
    rs.append(result("P3", "demo", 20, 1, 0, status="error"))  # failed: not a partner
    rs.append(result("P3", "col", 20, 1, 100))
    return rs


def test_pairs_are_matched_by_participant_and_seed_at_one_count() -> None:
    rs = four_pairs()
    assert paired_differences(rs, "col", "demo", 20) == [10.0, 20.0, 30.0, 40.0]
    assert [k for k, _, _ in paired_values(rs, "col", "demo", 20)] == [("P1", 0), ("P2", 0), ("P3", 0), ("P4", 0)]
    assert paired_values(rs, "col", "demo", 20)[0] == (("P1", 0), 60.0, 50.0)
    assert paired_differences(rs, "demo", "col", 20) == [-10.0, -20.0, -30.0, -40.0]
    assert paired_differences(rs, "col", "demo", 8) == []  # Demo alone at 8
    assert paired_differences(rs, "col", "int", 20) == []


def test_sign_flip_p_values_by_hand() -> None:
    # all 16 sign vectors of four positive differences: only all-plus and all-minus reach |100|
    assert sign_flip_pvalue([10, 20, 30, 40]) == (0.125, True)
    # [10, -20, 30, 40] sums to 60; |sum| >= 60 for the flips of nothing, of 10 (80) and of
    # -20 alone (100), and their negatives: 6 of 16
    assert sign_flip_pvalue([10, -20, 30, 40]) == (0.375, True)
    assert sign_flip_pvalue([10, 10, 10, 10]) == (0.125, True)  # constant: still exact
    assert sign_flip_pvalue([0, 0, 0]) == (1.0, True)  # no difference at all
    assert sign_flip_pvalue([5, 5, 5, 5, 5]) == (2 / 32, True)
    assert sign_flip_pvalue([0.1, 0.2, -0.3]) == (1.0, True)  # sum 0 up to rounding: every flip counts
    assert sign_flip_pvalue([40.0]) is None and sign_flip_pvalue([]) is None


def test_sign_flip_is_monte_carlo_above_16_pairs_and_repeatable() -> None:
    d = [float(k) for k in range(1, 18)]  # 17 pairs, all positive: exact p would be 2 / 2^17
    p, exact = sign_flip_pvalue(d, seed=3) or (math.nan, True)
    assert not exact
    assert 1 / (MONTE_CARLO_SIGN_FLIPS + 1) <= p < 1e-3
    assert sign_flip_pvalue(d, seed=3) == (p, False)


def test_wilcoxon_p_values_by_hand() -> None:
    # exact signed-rank distribution, n = 4: W- = 0 only for all-plus; two-sided 2 / 16
    assert wilcoxon_pvalue([10, 20, 30, 40]) == pytest.approx(0.125)
    assert wilcoxon_pvalue([-1, -2, -3, -4, -5]) == pytest.approx(2 / 32)
    assert wilcoxon_pvalue([0, 0, 0, 0]) == 1.0
    assert wilcoxon_pvalue([7]) is None


def test_paired_test_reports_the_sign_flip_as_primary_with_wilcoxon_beside() -> None:
    test = paired_test([10, 20, 30, 40])
    assert test is not None
    assert (test.p, test.exact) == (0.125, True) and test.p_wilcoxon == pytest.approx(0.125)
    assert paired_test([3]) is None


def test_bootstrap_interval_of_the_mean() -> None:
    ci = bootstrap_mean_ci([10, 20, 30, 40])
    assert ci is not None
    low, high = ci
    # symmetric data: about 25 -+ 1.96 * 5.59 (the bootstrap s.e. sqrt(125 / 4)), on the 2.5 grid
    # of resampled means
    assert low == pytest.approx(15.0, abs=2.5) and high == pytest.approx(35.0, abs=2.5)
    assert low + high == pytest.approx(50.0, abs=2.5)
    assert bootstrap_mean_ci([10, 20, 30, 40]) == ci  # fixed seed: the same report every time
    narrower = bootstrap_mean_ci([10, 20, 30, 40], confidence=0.5)
    assert narrower is not None and low < narrower[0] < narrower[1] < high


def test_bootstrap_degenerate_cases_have_no_interval() -> None:
    assert bootstrap_mean_ci([]) is None
    assert bootstrap_mean_ci([12.0]) is None
    assert bootstrap_mean_ci([10.0, 10.0, 10.0]) is None  # every resample has the same mean


def test_compare_paired_gathers_mean_interval_test_and_counts() -> None:
    rs = four_pairs()
    c = compare_paired(rs, "col", "demo", 20)
    assert c.n == 4 and c.mean == 25.0 and c.differences == (10.0, 20.0, 30.0, 40.0)
    assert c.ci is not None and c.test is not None and c.test.p == 0.125
    assert c.wins_ties_losses == (4, 0, 0)
    rs += [result("P1", "int", 20, 0, 60), result("P2", "int", 20, 0, 85), result("P3", "int", 20, 0, 60)]
    mixed = compare_paired(rs, "col", "int", 20)
    assert mixed.differences == (0.0, -5.0, 10.0) and mixed.wins_ties_losses == (1, 1, 1)
    empty = compare_paired(rs, "int", "demo", 8)
    assert empty.n == 0 and empty.mean is None and empty.ci is None and empty.test is None


def test_completion_per_1000_samples_by_hand() -> None:
    rs = [result("P1", "demo", 20, 0, 80, samples=2000), result("P2", "demo", 20, 0, 60, samples=3000),
          result("P1", "col", 20, 0, 90, samples=1500), result("P2", "col", 20, 0, 80, samples=1300),
          result("P3", "col", 20, 0, 0, samples=0, status="error")]
    demo = completion_per_1000_samples(rs, "demo", 20)
    col = completion_per_1000_samples(rs, "col", 20)
    assert demo == pytest.approx(70.0 / 2500.0 * 1000.0)  # 28.0
    assert col == pytest.approx(85.0 / 1400.0 * 1000.0)  # 60.71
    assert col is not None and demo is not None and col / demo == pytest.approx(2.1684, abs=1e-4)
    assert completion_per_1000_samples(rs, "int", 20) is None
    assert completion_per_1000_samples([result("P1", "int", 4, 0, 0, samples=0)], "int", 4) is None


def test_t_interval_by_hand() -> None:
    # mean 70, s.d. 20, s.e. 11.547, t(0.975, 2 d.f.) = 4.3027: 70 -+ 49.68
    low, high = t_interval([50.0, 70.0, 90.0]) or (math.nan, math.nan)
    assert low == pytest.approx(20.317, abs=1e-3) and high == pytest.approx(119.683, abs=1e-3)
    assert t_interval([5.0]) is None


def test_wilson_interval_still_holds() -> None:
    assert wilson_interval(0, 0) == (0.0, 1.0)
    low, high = wilson_interval(50, 100)
    assert low == pytest.approx(0.4038, abs=1e-4) and high == pytest.approx(0.5962, abs=1e-4)
