"""The CoL+ grids' preregistered analysis (docs/experiment.md, "CoL+: preregistration"), written
and committed before their runs:

    python results/colplus/analyse.py            # summary.json and table.md here

Reads ``scripted/results.jsonl`` and ``human-like/results.jsonl`` here (each: the committed trials
it reuses and the CoL+ grid's own). The unit is a (grid, participant, replicate) pair at one
count; the primary endpoints pool both grids' pairs (CoL+ − CoL at 20, then at 8); the rest is
secondary. Refuses to analyse while either grid is incomplete, as the plan says.
"""

from __future__ import annotations

import json
import statistics
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))

from companion.experiment.results import ResultsFile  # noqa: E402
from companion.statistics import bootstrap_mean_ci, paired_test  # noqa: E402

GRIDS = {"scripted": (("P1", "P2", "P3", "P4"), (0, 1, 2, 3)),
         "human-like": (tuple(f"H{i:02d}" for i in range(1, 9)), (0, 1))}
CONDITIONS = ("demo", "int", "col", "colplus")
COUNTS = (4, 8, 12, 20)
PRIMARY = (("colplus", "col", 20), ("colplus", "col", 8))
SECONDARY = [("colplus", "col", n) for n in (4, 12)] + [("colplus", "demo", n) for n in COUNTS]
TEACHER_PCT = 100.0  # the scripted expert on these 100 starts (results/precland/compare/table.md)
GOAL_PCT = 95.0  # "lands as often as its teacher": within five points of the expert
Cell = tuple[str, str, int]  # (grid, participant, replicate)


def completion(grid: str) -> dict[tuple[str, int, str, int], float]:
    """Completion % per (condition, count, participant, replicate) of one grid's ok trials."""
    out = {}
    for r in ResultsFile(HERE / grid / "results.jsonl").load():
        if r.status == "ok":
            t = r.trial
            out[(t.condition, t.interactions, t.participant, t.seed)] = r.completion_pct
    return out


def missing(grid: str, rates: dict[tuple[str, int, str, int], float]) -> list[str]:
    people, seeds = GRIDS[grid]
    return [f"{c}@{n} {p} s{s}" for c in CONDITIONS for n in COUNTS for p in people for s in seeds
            if (c, n, p, s) not in rates]


def compare(rates: dict[str, dict], a: str, b: str, n: int, grids: tuple[str, ...]) -> dict[str, object]:  # type: ignore[type-arg]
    """``a`` minus ``b`` at count ``n`` over the grids' pairs: mean, BCa interval, sign-flip p."""
    diffs = [rates[g][(a, n, p, s)] - rates[g][(b, n, p, s)] for g in grids
             for p in GRIDS[g][0] for s in GRIDS[g][1]]
    ci, test = bootstrap_mean_ci(diffs), paired_test(diffs)
    return {"a": a, "b": b, "interactions": n, "grids": list(grids), "pairs": len(diffs),
            "a_pct": round(statistics.fmean(rates[g][(a, n, p, s)] for g in grids for p in GRIDS[g][0]
                                            for s in GRIDS[g][1]), 2),
            "mean_diff_pts": round(statistics.fmean(diffs), 2),
            "ci95": None if ci is None else [round(ci[0], 2), round(ci[1], 2)],
            "p_sign_flip": None if test is None else round(test.p, 4),
            "p_exact": None if test is None else test.exact,
            "wins_ties_losses": [sum(d > 0 for d in diffs), sum(d == 0 for d in diffs), sum(d < 0 for d in diffs)]}


def regressions(rates: dict, grid: str, condition: str) -> int:  # type: ignore[type-arg]
    """Pairs whose @20 is more than 10 points below their @8."""
    people, seeds = GRIDS[grid]
    return sum(rates[(condition, 20, p, s)] < rates[(condition, 8, p, s)] - 10 for p in people for s in seeds)


def completion_detail(grid: str) -> dict[tuple[str, int, str, int], tuple[float, int, int]]:
    """(completion %, human samples, training successes) per (condition, count, participant, replicate)."""
    out = {}
    for r in ResultsFile(HERE / grid / "results.jsonl").load():
        if r.status == "ok":
            t = r.trial
            out[(t.condition, t.interactions, t.participant, t.seed)] = (r.completion_pct, r.human_samples,
                                                                         r.train_successes)
    return out


def teacher_pct(detail: dict, grid: str) -> dict[str, float]:  # type: ignore[type-arg]
    """Each participant's own landings in the 20 episodes it demonstrated (Demo@20's training
    episodes, the same starts as every condition's of that replicate), over its replicates."""
    people, seeds = GRIDS[grid]
    return {p: statistics.fmean(100.0 * detail[("demo", 20, p, s)][2] / 20 for s in seeds) for p in people}


def issue_goals(rates: dict, details: dict) -> dict[str, object]:  # type: ignore[type-arg]
    """The issue's goals, each reported as met or not with its figure (docs/experiment.md)."""
    def mean(grid: str, n: int, field: int = 0, people: tuple[str, ...] | None = None) -> float:
        ps, seeds = GRIDS[grid]
        return statistics.fmean(details[grid][("colplus", n, p, s)][field] for p in (people or ps) for s in seeds)

    goals: dict[str, object] = {}
    s20, s8, s8_samples = mean("scripted", 20), mean("scripted", 8), mean("scripted", 8, 1)
    goals["scripted: CoL+@20 >= 95 %"] = {"value": round(s20, 2), "met": s20 >= 95}
    goals["scripted: CoL+@8 >= 90 % with at most 1,000 human samples"] = {
        "value": round(s8, 2), "human_samples": round(s8_samples, 1), "met": s8 >= 90 and s8_samples <= 1000}
    teachers = teacher_pct(details["human-like"], "human-like")
    good = tuple(p for p, v in teachers.items() if v >= 90)
    h20 = mean("human-like", 20, people=good) if good else None
    goals["human-like: CoL+@20 >= 90 % over those who land >= 90 % of their own episodes"] = {
        "participants": list(good), "value": None if h20 is None else round(h20, 2), "met": h20 is not None and h20 >= 90}
    own = {p: (round(mean("human-like", 20, people=(p,)), 2), round(v, 2)) for p, v in teachers.items()}
    goals["human-like: every participant's CoL+@20 >= their own success - 5 points"] = {
        "colplus_at_20_and_own": own, "met": all(c >= t - 5 for c, t in own.values())}
    for grid in GRIDS:
        people, seeds = GRIDS[grid]
        worse = [f"{p} s{s}" for p in people for s in seeds
                 if rates[grid][("colplus", 20, p, s)] < rates[grid][("colplus", 8, p, s)] - 10]
        goals[f"{grid}: every pair's CoL+@20 >= CoL+@8 - 10 points"] = {"pairs_below": worse, "met": not worse}
    goals["teachers"] = {g: {p: round(v, 2) for p, v in teacher_pct(details[g], g).items()} for g in GRIDS}
    return goals


def verdict(c: dict) -> str:  # type: ignore[type-arg]
    ci = c["ci95"]
    return "not told apart" if ci is None or ci[0] <= 0 <= ci[1] else "better" if ci[0] > 0 else "worse"


def gather_environments() -> None:
    """The grids' environment records, each once, marked with its grid, in environment.jsonl here
    (what every committed results folder has): written at every call, whole grids or not."""
    records = []
    for grid in GRIDS:
        path = HERE / grid / "environment.jsonl"
        if path.exists():
            records += [json.dumps({"grid": grid, **json.loads(line)}, sort_keys=True)
                        for line in path.read_text().splitlines() if line.strip()]
    if records:
        (HERE / "environment.jsonl").write_text("\n".join(records) + "\n")


def main() -> None:
    gather_environments()
    rates = {g: completion(g) for g in GRIDS}
    gaps = {g: missing(g, rates[g]) for g in GRIDS}
    if any(gaps.values()):
        for g, m in gaps.items():
            print(f"{g}: {len(m)} trials missing" + (f", e.g. {', '.join(m[:4])}" if m else ""))
        raise SystemExit("not analysed: the plan analyses the grids only when both are whole")
    both = tuple(GRIDS)
    summary: dict[str, object] = {}
    rows = ["| endpoint | grids | pairs | CoL+ % | difference, points [95 % CI] | p (sign flip) | wins/ties/losses | verdict |",
            "| --- | --- | ---: | ---: | --- | ---: | --- | --- |"]
    for kind, endpoints in (("primary", PRIMARY), ("secondary", SECONDARY)):
        for a, b, n in endpoints:
            for grids in ((both,) if kind == "primary" else ()) + tuple((g,) for g in GRIDS) + ((both,) if kind == "secondary" else ()):
                c = compare(rates, a, b, n, grids)
                c["verdict"] = verdict(c)
                name = f"{kind}: {a} - {b} @{n}"
                summary[f"{name} [{'+'.join(grids)}]"] = c
                rows.append(f"| {name} | {'+'.join(grids)} | {c['pairs']} | {c['a_pct']} | {c['mean_diff_pts']:+} "
                            f"{c['ci95']} | {c['p_sign_flip']} | {c['wins_ties_losses']} | {c['verdict']} |")
    summary["regressions"] = {g: {c: regressions(rates[g], g, c) for c in CONDITIONS} for g in GRIDS}
    plus20 = statistics.fmean(rates[g][("colplus", 20, p, s)] for g in GRIDS for p in GRIDS[g][0] for s in GRIDS[g][1])
    summary["colplus_at_20_pct"] = round(plus20, 2)
    summary["teacher_goal"] = {"teacher_pct": TEACHER_PCT, "goal_pct": GOAL_PCT, "met": plus20 >= GOAL_PCT}
    summary["issue_goals"] = issue_goals(rates, {g: completion_detail(g) for g in GRIDS})
    for name, goal in summary["issue_goals"].items():  # type: ignore[union-attr]
        if name != "teachers":
            rows.append(f"- {name}: {'met' if goal['met'] else 'not met'} ({goal})")
    rows.append(f"\nCoL+@20 over both grids: {plus20:.2f} % (goal {GOAL_PCT} %, the expert {TEACHER_PCT} %). "
                f"Regressions (@20 > 10 points below @8): {summary['regressions']}.")
    (HERE / "summary.json").write_text(json.dumps(summary, indent=1) + "\n")
    (HERE / "table.md").write_text("\n".join(rows) + "\n")
    print("\n".join(rows))


if __name__ == "__main__":
    main()
