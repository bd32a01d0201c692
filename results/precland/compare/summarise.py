"""The comparison's figures from the committed episode records, by the plan in docs/baselines.md
("The operator's baseline", written before the runs). Writes summary.json and table.md here.

    python results/precland/compare/summarise.py
"""

from __future__ import annotations

import json
import statistics
from pathlib import Path

import numpy as np

from companion.statistics import wilson_interval

HERE = Path(__file__).resolve().parent
EPISODES = HERE / "episodes"
LEVELS = ("0.2", "0")
PARTICIPANTS = ("P1", "P2", "P3", "P4")
ARMS = {"precland-px4": "precland, PX4 (our SITL)", "precland-ardupilot": "precland, ArduPilot (our SITL)",
        "expert": "scripted expert"}
POLICY_ARMS = {"col": "CoL@20 (P1-P4, replicate 0)", "demo": "Demo@20 (P1-P4, replicate 0)"}
REAL = {"real-px4-precland": "precland, real PX4 SIH", "real-px4-expert": "scripted expert, real PX4 SIH"}
RESAMPLES, SEED = 10_000, 0
SUCCESS_RADIUS_M = 0.5


def read(name: str) -> list[dict]:
    path = EPISODES / f"{name}.jsonl"
    return [json.loads(line) for line in path.read_text().splitlines()] if path.exists() else []


def describe(records: list[dict]) -> dict:
    """Success rate with a Wilson interval, outcomes, touchdown distance and time to land."""
    n = len(records)
    wins = sum(1 for r in records if r["success"])
    low, high = wilson_interval(wins, n) if n else (float("nan"), float("nan"))
    outcomes: dict[str, int] = {}
    for r in records:
        outcomes[r["outcome"]] = outcomes.get(r["outcome"], 0) + 1
    down = [r for r in records if r["outcome"] == "touchdown" and r["touchdown_distance_m"] is not None]
    distances = sorted(r["touchdown_distance_m"] for r in down)
    return {
        "episodes": n, "successes": wins,
        "success_rate_pct": round(100.0 * wins / n, 2) if n else None,
        "wilson95_pct": [round(100.0 * low, 2), round(100.0 * high, 2)] if n else None,
        "outcomes": dict(sorted(outcomes.items())),
        "touchdown_distance_m_median": round(statistics.median(distances), 3) if distances else None,
        "touchdown_distance_m_p90": round(float(np.percentile(distances, 90)), 3) if distances else None,
        "time_to_land_s_median": round(statistics.median(r["sim_time_s"] for r in down), 2) if down else None,
        "true_touchdown_distance_m_median": _median([r.get("true_touchdown_distance_m") for r in down]),
        # a real autopilot: success by the simulator's ground truth (the record's is by the estimate)
        "successes_by_truth": sum(1 for r in down if (r.get("true_touchdown_distance_m") or 1e9) <= SUCCESS_RADIUS_M)
        if any(r.get("true_touchdown_distance_m") is not None for r in down) else None,
    }


def _median(values: list) -> float | None:
    known = [v for v in values if v is not None]
    return round(statistics.median(known), 3) if known else None


def by_seed(records: list[dict]) -> dict[int, float]:
    return {int(r["seed"]): 1.0 if r["success"] else 0.0 for r in records}


def paired(arm: list[dict], policies: list[list[dict]]) -> dict | None:
    """Per start: the arm's success minus the share of the policies that succeeded there; the
    mean in points with a 95 % percentile bootstrap interval over the starts."""
    if not arm or not policies or any(not p for p in policies):
        return None
    a, ps = by_seed(arm), [by_seed(p) for p in policies]
    seeds = sorted(set(a).intersection(*ps))
    d = np.array([a[s] - sum(p[s] for p in ps) / len(ps) for s in seeds]) * 100.0
    rng = np.random.default_rng(SEED)
    means = d[rng.integers(0, len(d), size=(RESAMPLES, len(d)))].mean(axis=1)
    low, high = np.percentile(means, [2.5, 97.5])
    return {"starts": len(seeds), "policies": len(ps), "mean_difference_points": round(float(d.mean()), 2),
            "bootstrap95_points": [round(float(low), 2), round(float(high), 2)],
            "starts_arm_better_tied_worse": [int((d > 0).sum()), int((d == 0).sum()), int((d < 0).sum())]}


def summary() -> dict:
    out: dict = {"levels": {}, "real_autopilot": {}}
    for level in LEVELS:
        rows: dict = {}
        for arm in ARMS:
            rows[arm] = describe(read(f"{arm}-level-{level}"))
        pols = {}
        for cond in POLICY_ARMS:
            each = {p: read(f"{p}-{cond}-20-s0-level-{level}") for p in PARTICIPANTS}
            found = {p: r for p, r in each.items() if r}
            pooled = describe([r for recs in found.values() for r in recs])
            pooled["policies"] = sorted(found)
            pooled["each_success_rate_pct"] = {p: describe(r)["success_rate_pct"] for p, r in found.items()}
            rows[cond] = pooled
            pols[cond] = list(found.values())
        comparisons = {}
        for arm in ("precland-px4", "precland-ardupilot", "expert"):
            for cond in POLICY_ARMS:
                comparisons[f"{arm} - {cond}@20"] = paired(read(f"{arm}-level-{level}"), pols[cond])
        out["levels"][level] = {"arms": rows, "paired": comparisons}
    for name in REAL:
        out["real_autopilot"][name] = describe(read(name))
    return out


def _row(label: str, s: dict) -> str:
    if not s["episodes"]:
        return f"| {label} | not run | | | | |"
    ci = s["wilson95_pct"]
    outcomes = ", ".join(f"{k} {v}" for k, v in s["outcomes"].items())
    return (f"| {label} | {s['success_rate_pct']:.1f} % [{ci[0]:.1f}, {ci[1]:.1f}] ({s['successes']}/{s['episodes']}) "
            f"| {outcomes} | {_fmt(s['touchdown_distance_m_median'])} / {_fmt(s['touchdown_distance_m_p90'])} "
            f"| {_fmt(s['time_to_land_s_median'], 1)} |")


def _fmt(x: float | None, digits: int = 2) -> str:
    return "-" if x is None else f"{x:.{digits}f}"


def table(s: dict) -> str:
    lines = ["# The operator's baseline against the learned policies", "",
             "Made by `python results/precland/compare/summarise.py` from `episodes/`; the plan is "
             "docs/baselines.md, \"The operator's baseline\". Success: touchdown within 0.5 m of the pad's "
             "centre (95 % Wilson interval); distance and time among touchdowns.", ""]
    for level, block in s["levels"].items():
        lines += [f"## Level {level}", "", "| arm | success | outcomes | touchdown distance m, median / p90 | time to land s, median |",
                  "| --- | ---: | --- | ---: | ---: |"]
        for arm, label in {**ARMS, **POLICY_ARMS}.items():
            lines.append(_row(label, block["arms"][arm]))
        for cond in POLICY_ARMS:
            each = block["arms"][cond].get("each_success_rate_pct") or {}
            if each:
                lines.append(f"\n{POLICY_ARMS[cond]}, each policy: " + ", ".join(f"{p} {v:.0f} %" for p, v in each.items()))
        lines += ["", "| paired by start (points) | mean | 95 % bootstrap | starts better / tied / worse |",
                  "| --- | ---: | ---: | ---: |"]
        for name, c in block["paired"].items():
            if c is None:
                lines.append(f"| {name} | not run | | |")
            else:
                b = c["bootstrap95_points"]
                lines.append(f"| {name} | {c['mean_difference_points']:+.2f} | [{b[0]:+.2f}, {b[1]:+.2f}] | "
                             f"{'/'.join(str(x) for x in c['starts_arm_better_tied_worse'])} |")
        lines.append("")
    lines += ["## Real PX4 SIH (level 0: our SITL's disturbances do not exist there; success from its reported position)", "",
              "| arm | success | outcomes | touchdown distance m, median / p90 | time to land s, median |",
              "| --- | ---: | --- | ---: | ---: |"]
    for name, label in REAL.items():
        lines.append(_row(label, s["real_autopilot"][name]))
    for name in REAL:
        row = s["real_autopilot"][name]
        if row["true_touchdown_distance_m_median"] is not None:
            lines.append(f"\n{REAL[name]}: by SIH's ground truth, {row['successes_by_truth']} of {row['episodes']} within "
                         f"0.5 m of the pad, median touchdown distance {row['true_touchdown_distance_m_median']:.2f} m.")
    return "\n".join(lines) + "\n"


def main() -> None:
    s = summary()
    (HERE / "summary.json").write_text(json.dumps(s, indent=1) + "\n")
    (HERE / "table.md").write_text(table(s))
    print(json.dumps({"written": ["summary.json", "table.md"]}))


if __name__ == "__main__":
    main()
