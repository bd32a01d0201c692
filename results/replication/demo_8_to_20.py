"""Demo at 20 demonstrations against Demo at 8, paired by participant and replicate seed, in the
standing replication: does Demo improve with more demonstrations on new draws? (The paper grid's
replicates 0-3 showed no improvement; README named this run as the check before it ran.)
The same statistics as the report's paired table: BCa bootstrap of the mean difference (9,999
resamples, seed 0) and an exact two-sided sign-flip p. Prints one JSON object.

    python results/replication/demo_8_to_20.py > results/replication/demo_8_to_20.json
"""

from __future__ import annotations

import itertools
import json
from pathlib import Path

import numpy as np
from scipy import stats

from companion.experiment.results import ResultsFile
from companion.statistics import counted

HERE = Path(__file__).resolve().parent


def completion_by_cell() -> dict[tuple[str, str, int, int], float]:
    cells = {}
    for r in counted(ResultsFile(HERE / "results.jsonl").load()):
        t = r.trial
        cells[(t.participant, t.condition, t.interactions, t.seed)] = 100.0 * r.eval_successes / r.eval_runs
    return cells


def main() -> None:
    cells = completion_by_cell()
    pairs = sorted((p, s) for (p, c, n, s) in cells if c == "demo" and n == 8 and (p, "demo", 20, s) in cells)
    diffs = np.array([cells[(p, "demo", 20, s)] - cells[(p, "demo", 8, s)] for p, s in pairs])
    ci = stats.bootstrap((diffs,), np.mean, n_resamples=9999, method="BCa", random_state=0).confidence_interval
    observed = abs(diffs.mean())
    flips = [abs((diffs * np.array(signs)).mean()) >= observed - 1e-12
             for signs in itertools.product((1.0, -1.0), repeat=len(diffs))]
    print(json.dumps({"comparison": "Demo@20 - Demo@8", "pairs": len(diffs), "mean_difference_points": round(float(diffs.mean()), 2),
                      "bca95": [round(float(ci.low), 2), round(float(ci.high), 2)],
                      "p_sign_flip_exact": round(sum(flips) / len(flips), 4),
                      "better_tie_worse": [int((diffs > 0).sum()), int((diffs == 0).sum()), int((diffs < 0).sum())]}))


if __name__ == "__main__":
    main()
