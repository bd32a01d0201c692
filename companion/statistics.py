"""Statistics shared by the CLI, the experiment and the RL baselines: intervals of success
rates and, for the experiment's report, paired comparisons.

The experiment's comparisons are *paired*: a participant's Demo, Int and CoL trials of one
replicate seed share the training starts and the initial weights, so the difference between
two conditions within such a pair removes the participant's and the seed's share of the
variation. The pair is the unit: (participant, seed) at one interaction count.

scipy is imported inside the functions that need it, so that ``col`` starts quickly.
"""

from __future__ import annotations

import inspect
import math
import statistics
import warnings
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol, TypeVar

import numpy as np

PairKey = tuple[str, int]
"""(participant, replicate seed): the unit of a paired comparison."""
BOOTSTRAP_METHOD = "BCa"
BOOTSTRAP_RESAMPLES = 9999
WILCOXON_ZERO_METHOD = "zsplit"
EXACT_SIGN_FLIP_MAX_PAIRS = 16
"""Up to 16 pairs the sign-flip test enumerates all 2^n sign vectors (65,536)."""
MONTE_CARLO_SIGN_FLIPS = 2**16


def wilson_interval(successes: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """95 % Wilson score interval of a success rate (sound for small n and rates near 0 or 1)."""
    if n == 0:
        return 0.0, 1.0
    p = successes / n
    denom = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    return max(0.0, centre - half), min(1.0, centre + half)


class TrialLike(Protocol):
    """What the comparisons need of a trial (``companion.experiment.grid.Trial`` is one);
    a protocol, so that this module imports nothing from the experiment."""

    @property
    def participant(self) -> str: ...
    @property
    def condition(self) -> str: ...
    @property
    def interactions(self) -> int: ...
    @property
    def seed(self) -> int: ...


class ResultLike(Protocol):
    """What the comparisons need of a trial's result (``TrialResult`` is one)."""

    @property
    def trial(self) -> TrialLike: ...
    @property
    def status(self) -> str: ...
    @property
    def completion_pct(self) -> float: ...
    @property
    def human_samples(self) -> int: ...


R = TypeVar("R", bound="ResultLike")


def counted(results: Iterable[R]) -> list[R]:
    """The one rule every reader of ``results.jsonl`` uses: a trial counts by its latest ``ok``
    line; an ``error`` line (a retry that failed, a collision) never hides an ``ok`` one, and a
    trial with no ``ok`` line does not count. In order of the trials' first appearance."""
    latest: dict[tuple[str, str, int, int], R] = {}
    order: dict[tuple[str, str, int, int], int] = {}
    for r in results:
        t = r.trial
        key = (t.participant, t.condition, t.interactions, t.seed)
        order.setdefault(key, len(order))
        if r.status == "ok":
            latest[key] = r
    return [latest[k] for k in sorted(latest, key=order.__getitem__)]


def finished(results: Iterable[R], condition: str, interactions: int) -> list[R]:
    """The cell's results that count (:func:`counted`), in (participant, seed) order."""
    cell = [r for r in counted(results) if r.trial.condition == condition and r.trial.interactions == interactions]
    return sorted(cell, key=lambda r: (r.trial.participant, r.trial.seed))


def paired_values(results: Sequence[ResultLike], a: str, b: str,
                  interactions: int) -> list[tuple[PairKey, float, float]]:
    """(pair, completion % of ``a``, completion % of ``b``) for every (participant, seed) that
    finished both conditions at this count; a result without its partner is left out."""
    mine, theirs = (_completion_by_pair(finished(results, c, interactions)) for c in (a, b))
    return [(k, mine[k], theirs[k]) for k in sorted(mine.keys() & theirs.keys())]


def _completion_by_pair(cell: Sequence[ResultLike]) -> dict[PairKey, float]:
    return {(r.trial.participant, r.trial.seed): r.completion_pct for r in cell}


def paired_differences(results: Sequence[ResultLike], a: str, b: str, interactions: int) -> list[float]:
    """``a`` minus ``b`` in completion points, one per (participant, seed) pair, in pair order."""
    return [va - vb for _, va, vb in paired_values(results, a, b, interactions)]


def _rng_kwargs(seed: int) -> dict[str, Any]:
    """scipy >= 1.15 takes ``rng``; older versions ``random_state``: the same seed either way."""
    from scipy import stats

    if "rng" in inspect.signature(stats.bootstrap).parameters:
        return {"rng": np.random.default_rng(seed)}
    return {"random_state": np.random.default_rng(seed)}


def bootstrap_mean_ci(values: Sequence[float], confidence: float = 0.95, seed: int = 0,
                      n_resamples: int = BOOTSTRAP_RESAMPLES) -> tuple[float, float] | None:
    """BCa bootstrap interval of the mean (``scipy.stats.bootstrap``, one sample: for paired
    data, the differences), with a fixed seed so that a report repeats exactly.

    BCa rather than percentile: it corrects the percentile interval for the bootstrap
    distribution's bias and skew, and differences of completion rates near the 100 % ceiling
    are skewed. None when there is no interval to give: fewer than two values, all values equal
    (every resample has the same mean), or BCa's acceleration undefined.
    """
    if len(values) < 2 or len(set(values)) == 1:
        return None
    from scipy import stats

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # DegenerateDataWarning: handled below as None
        res = stats.bootstrap((np.asarray(values, dtype=float),), np.mean, confidence_level=confidence,
                              n_resamples=n_resamples, method=BOOTSTRAP_METHOD, **_rng_kwargs(seed))
    low, high = float(res.confidence_interval.low), float(res.confidence_interval.high)
    return (low, high) if math.isfinite(low) and math.isfinite(high) else None


def _sign_vectors(n: int, seed: int) -> tuple[np.ndarray, bool]:
    """Every +-1 vector of length n (exact), or a fixed-seed random sample of them."""
    if n <= EXACT_SIGN_FLIP_MAX_PAIRS:
        bits = (np.arange(2**n)[:, None] >> np.arange(n)) & 1
        return 1 - 2 * bits, True
    rng = np.random.default_rng(seed)
    return rng.choice(np.array([-1, 1]), size=(MONTE_CARLO_SIGN_FLIPS, n)), False


def sign_flip_pvalue(differences: Sequence[float], seed: int = 0) -> tuple[float, bool] | None:
    """Two-sided paired permutation test of the mean difference: under "no difference between
    the conditions" each pair's difference is as likely negative as positive, so the observed
    |mean| is compared with the |mean| of every sign flip. Returns (p, exact).

    Exact (all 2^n flips, p = share of flips at least as extreme) up to 16 pairs; above that a
    Monte-Carlo sample of 65,536 flips with a fixed seed and p = (k + 1) / (R + 1). Zero
    differences need no rule (flipping them changes nothing). None below two pairs.
    """
    n = len(differences)
    if n < 2:
        return None
    d = np.asarray(differences, dtype=float)
    signs, exact = _sign_vectors(n, seed)
    null = np.abs(signs @ d)
    observed = abs(float(d.sum()))
    tolerance = 1e-9 * max(1.0, float(np.abs(d).sum()))  # equal sums must count as equal
    extreme = int(np.count_nonzero(null >= observed - tolerance))
    if exact:
        return extreme / len(signs), True
    return (extreme + 1) / (len(signs) + 1), False


def wilcoxon_pvalue(differences: Sequence[float]) -> float | None:
    """Two-sided Wilcoxon signed-rank p-value (``scipy.stats.wilcoxon``), a rank-based check
    on the sign-flip test. ``zero_method='zsplit'``: a tie between the conditions keeps its
    rank, split between both signs, so ties count as evidence of no difference rather than
    being dropped. scipy's ``method='auto'``: the exact table without zeros or ties (n <= 50);
    with them, exhaustive permutations up to 13 pairs (recent scipy) or the normal
    approximation. None below two pairs; 1.0 when every difference is zero."""
    if len(differences) < 2:
        return None
    if all(x == 0 for x in differences):
        return 1.0
    from scipy import stats

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # "switching to normal approximation" with zeros/ties
        res = stats.wilcoxon(np.asarray(differences, dtype=float), zero_method=WILCOXON_ZERO_METHOD)
    p = float(res.pvalue)
    return p if math.isfinite(p) else None


@dataclass(frozen=True)
class PairedTest:
    """The paired test's p-values: the sign-flip permutation test is the primary one."""

    p: float
    exact: bool
    p_wilcoxon: float | None


def paired_test(differences: Sequence[float], seed: int = 0) -> PairedTest | None:
    """The sign-flip permutation p-value (primary: it tests the mean difference the report
    shows, exactly for small n) with the Wilcoxon signed-rank p-value beside it."""
    flip = sign_flip_pvalue(differences, seed)
    if flip is None:
        return None
    return PairedTest(flip[0], flip[1], wilcoxon_pvalue(differences))


@dataclass(frozen=True)
class PairedComparison:
    """Condition ``a`` against ``b`` at one interaction count, over matched pairs."""

    a: str
    b: str
    interactions: int
    differences: tuple[float, ...]
    ci: tuple[float, float] | None
    test: PairedTest | None

    @property
    def n(self) -> int:
        return len(self.differences)

    @property
    def mean(self) -> float | None:
        return statistics.fmean(self.differences) if self.differences else None

    @property
    def wins_ties_losses(self) -> tuple[int, int, int]:
        """Pairs where ``a`` did better, the same, worse: the raw picture behind the tests."""
        d = self.differences
        return sum(x > 0 for x in d), sum(x == 0 for x in d), sum(x < 0 for x in d)


def compare_paired(results: Sequence[ResultLike], a: str, b: str, interactions: int,
                   confidence: float = 0.95, seed: int = 0) -> PairedComparison:
    """``a`` minus ``b`` in completion points: mean difference, its bootstrap interval, tests."""
    d = paired_differences(results, a, b, interactions)
    return PairedComparison(a, b, interactions, tuple(d), bootstrap_mean_ci(d, confidence, seed),
                            paired_test(d, seed))


def completion_per_1000_samples(results: Sequence[ResultLike], condition: str,
                                interactions: int) -> float | None:
    """Mean completion % per 1,000 mean human samples: what a condition gives back for the
    person's effort (the paper's per-sample comparison). None without results or samples."""
    cell = finished(results, condition, interactions)
    if not cell:
        return None
    samples = statistics.fmean(r.human_samples for r in cell)
    if samples <= 0:
        return None
    return statistics.fmean(r.completion_pct for r in cell) / samples * 1000.0


def t_interval(values: Sequence[float], confidence: float = 0.95) -> tuple[float, float] | None:
    """Student-t interval of the mean (mean +- t * s.e.): deterministic and consistent with the
    table's standard errors. None below two values."""
    if len(values) < 2:
        return None
    from scipy import stats

    n = len(values)
    mean = statistics.fmean(values)
    half = float(stats.t.ppf(0.5 + confidence / 2, n - 1)) * statistics.stdev(values) / math.sqrt(n)
    return mean - half, mean + half
