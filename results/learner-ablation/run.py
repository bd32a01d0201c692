"""The learner switches' ablation (issue: the learner reaches its teacher), preregistered in
results/learner-ablation/PLAN.md before any of its runs. Steps, from the repository's root, each
resumable (`col experiment` resumes a results folder; a finished arm is skipped):

    python results/learner-ablation/run.py configs            # write each arm's experiment file
    python results/learner-ablation/run.py code [--commit C]  # the library the runs use: HEAD, exported
    python results/learner-ablation/run.py run [ARM ...]      # col experiment per arm (runs/learner-ablation/)
    python results/learner-ablation/run.py collect [ARM ...]  # per trial and per start into results/learner-ablation/
    python results/learner-ablation/run.py analyse            # summary.json and table.md, as PLAN.md says

``--round 2`` before the step runs the second round instead (PLAN.md, amendment 2): replicates 2
and 3, the arms of ROUND_SWITCHES[2], everything under round-2/ (here and in runs/). ``--round 3``
runs the combination (amendment 3): the ``colplus`` condition (DART with the weighting) on every
cell of the first two rounds, replicates 0-3, under round-3/, analysed against both rounds' arms.
``--round 4`` runs CoL+ with a 5-member ensemble (amendment 4) on the same 96 cells, under
round-4/, analysed against round 3's CoL+; ``--round 5`` CoL+ with the Huber loss (amendment 5),
under round-5/, the same way.

An arm is SET-SWITCH: SET scripted (P1-P4, the paper's level, configs/paper.toml) or human-like
(H01-H08, configs/human-like.toml); SWITCH base (every switch off: the paper's CoL) or one switch
on. The runs use one commit's library, exported clean (``git archive``) to
runs/learner-ablation/code/ (its commit in COMMIT there), whatever the working tree holds
meanwhile. Every arm trains CoL at 8 and 20 interactions, replicates 0 and 1, and flies each final
policy on the 50 validation starts from seed 600000, never on the held-out starts from 100000.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
RUNS = ROOT / "runs" / "learner-ablation"
CODE = RUNS / "code"
SETS = {"scripted": ("configs/paper.toml", ["P1", "P2", "P3", "P4"]),
        "human-like": ("configs/human-like.toml", [f"H{i:02d}" for i in range(1, 9)])}
SWITCHES: dict[str, dict[str, object]] = {
    "base": {},
    "mirror": {"mirror_augment": True},
    "holdout": {"holdout_stop": True},
    "weighting": {"intervention_weight": 2.0, "takeover_steps": 10, "takeover_weight": 4.0},
    "dart": {"demo_noise_std": 0.2},  # added in PLAN.md's amendment 1, before any dart run
    "ensemble": {"ensemble_members": 5},  # amendment 4: on top of CoL+, before any ensemble run
    "huber": {"huber_delta": 0.1},  # amendment 5: on top of CoL+, before any huber run
}
"""Each switch's settings, fixed in PLAN.md before the runs (the rest at their defaults)."""
EXPERIMENT = {"conditions": '["col"]', "interactions": "[8, 20]", "seeds": "[0, 1]",
              "eval_runs": "50", "eval_seed": "600000"}
ROUND_SEEDS = {1: "[0, 1]", 2: "[2, 3]", 3: "[0, 1, 2, 3]", 4: "[0, 1, 2, 3]", 5: "[0, 1, 2, 3]"}
"""Each round's replicates: the second (PLAN.md, amendment 2) on cells the first never saw."""
ROUND_SWITCHES = {1: ["base", "mirror", "holdout", "weighting", "dart"], 2: ["base", "mirror", "weighting", "dart"],
                  3: ["colplus"], 4: ["ensemble"], 5: ["huber"]}
"""Each round's arms: the second retries the switches the first did not show, and DART again; the
third is the combination, the ``colplus`` condition (its switches come with the condition,
companion/learning/col_plus.py, so its arm adds no learner keys); the fourth (amendment 4) is CoL+
with a 5-member ensemble, against the third round's CoL+ on the same cells; the fifth
(amendment 5) CoL+ with the Huber loss, the same way."""
ROUND_CONDITIONS = {1: '["col"]', 2: '["col"]', 3: '["colplus"]', 4: '["colplus"]', 5: '["colplus"]'}
COMBINATION = "colplus"
COMBINED_WITH = ("base", "dart", "weighting")
"""What the combination is compared with (PLAN.md, amendment 3), each pooled over rounds 1 and 2."""
BOOT_SEED = 0


class Round:
    """Where one round's files live, here and under runs/: the first round's at the top, as
    committed; a later round's in round-N/ of each."""

    def __init__(self, number: int) -> None:
        self.number = number
        self.here = HERE if number == 1 else HERE / f"round-{number}"
        self.runs = RUNS if number == 1 else RUNS / f"round-{number}"
        self.code = self.runs / "code"
        self.arms = [f"{s}-{w}" for s in SETS for w in ROUND_SWITCHES[number]]
        self.experiment = {**EXPERIMENT, "seeds": ROUND_SEEDS[number], "conditions": ROUND_CONDITIONS[number]}

    def rel(self, path: Path) -> str:
        return str(path.relative_to(ROOT))


def toml_value(v: object) -> str:
    return "true" if v is True else "false" if v is False else json.dumps(v)


def arm_config(arm: str, rnd: Round) -> str:
    """The set's experiment file with the round's [experiment] and the switch's learner keys."""
    set_name, switch = arm.split("-", 1) if not arm.startswith("human-like") else ("human-like", arm[11:])
    source, people = SETS[set_name]
    text = (ROOT / source).read_text()
    values = {**rnd.experiment, "participants": json.dumps(people)}
    for key, value in values.items():
        text, n = re.subn(rf"^{key} = .*$", f"{key} = {value}", text, count=1, flags=re.M)
        if n != 1:
            raise SystemExit(f"{source}: no '{key} =' line in [experiment]")
    keys = "".join(f"{k} = {toml_value(v)}\n" for k, v in SWITCHES.get(switch, {}).items())
    text, n = re.subn(r'^\[companion\.learner\]\nmode = "budgeted"\n', lambda m: m.group(0) + keys, text,
                      count=1, flags=re.M)
    if n != 1:
        raise SystemExit(f"{source}: no [companion.learner] table with mode = \"budgeted\"")
    which = "" if rnd.number == 1 else f", round {rnd.number}"
    header = f"# The learner ablation's arm {arm}{which} (results/learner-ablation/PLAN.md), made from {source}\n"
    return header + text


def configs(rnd: Round) -> None:
    for arm in rnd.arms:
        path = rnd.here / "configs" / f"{arm}.toml"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(arm_config(arm, rnd))
        print(rnd.rel(path))


def code(rnd: Round, commit: str = "HEAD") -> None:
    """The round's library: the repository at ``commit`` as committed (a later session continues
    with the commit the round's first arms ran at, RUN.md)."""
    from colcommon.code_export import export_commit

    head, made = export_commit(ROOT, rnd.code, commit)
    print(f"{rnd.rel(rnd.code)}: {head}" if made else f"{rnd.rel(rnd.code)} holds {head} already")


def run(rnd: Round, arms: list[str]) -> None:
    """``col experiment`` per arm, from inside the export (its configs are the committed ones)."""
    if not (rnd.code / "COMMIT").exists():
        raise SystemExit("no exported library: run the 'code' step first")
    for arm in arms:
        config = rnd.rel(rnd.here / "configs" / f"{arm}.toml")
        cmd = [str(ROOT / ".venv/bin/col"), "experiment", "--config", config,
               "--workers", "2", "--out", str(rnd.runs / arm)]
        print(" ".join(cmd), flush=True)
        subprocess.run(cmd, check=True, cwd=rnd.code, env={**os.environ, "PYTHONPATH": str(rnd.code)})


def collect(rnd: Round, arms: list[str]) -> None:
    """Each arm's trial lines, environment and timings, and one line per validation start."""
    for arm in arms:
        src, dst = rnd.runs / arm, rnd.here / arm
        dst.mkdir(parents=True, exist_ok=True)
        for name in ("results.jsonl", "environment.jsonl", "timings.jsonl"):  # paths as the repository's, not this machine's
            (dst / name).write_text((src / name).read_text().replace(f"{ROOT}/", ""))
        lines = []
        for trial in sorted((src / "trials").iterdir()):
            for line in (trial / "eval_episodes.jsonl").read_text().splitlines():
                ep = json.loads(line)
                lines.append(json.dumps({"trial": trial.name, "seed": ep["seed"], "outcome": ep["outcome"],
                                         "success": ep["success"],
                                         "distance_m": ep["touchdown_distance_m"]}))
        (dst / "per_start.jsonl").write_text("\n".join(lines) + "\n")
        gather_environments(rnd)
        print(rnd.rel(dst), len(lines), "starts")


def gather_environments(rnd: Round) -> None:
    """The arms' environment records, each once, in the round's environment.jsonl (what every
    committed results folder has), marked with their arm."""
    records = []
    for arm in rnd.arms:
        path = rnd.here / arm / "environment.jsonl"
        if path.exists():
            records += [json.dumps({"arm": arm, **json.loads(line)}, sort_keys=True)
                        for line in path.read_text().splitlines() if line.strip()]
    (rnd.here / "environment.jsonl").write_text("\n".join(records) + "\n")


def rates(folder: Path) -> dict[tuple[str, int, int], float]:
    """Validation success (%) per (participant, interactions, replicate) of one arm's folder."""
    out = {}
    for line in (folder / "results.jsonl").read_text().splitlines():
        r = json.loads(line)
        if r["status"] == "ok":
            t = r["trial"]
            out[(t["participant"], t["interactions"], t["seed"])] = 100.0 * r["eval_successes"] / r["eval_runs"]
    return out


def paired(base: dict, other: dict, keep) -> dict[str, object]:  # type: ignore[type-arg]
    from companion.statistics import bootstrap_mean_ci

    cells = sorted(k for k in base if k in other and keep(k))
    diffs = [other[k] - base[k] for k in cells]
    ci = bootstrap_mean_ci(diffs, seed=BOOT_SEED) if diffs else None
    return {"cells": len(cells), "base_pct": round(sum(base[k] for k in cells) / max(len(cells), 1), 2),
            "switch_pct": round(sum(other[k] for k in cells) / max(len(cells), 1), 2),
            "mean_diff_pts": round(sum(diffs) / max(len(diffs), 1), 2),
            "ci95": None if ci is None else [round(ci[0], 2), round(ci[1], 2)]}


def regressions(r: dict) -> int:  # type: ignore[type-arg]
    """(participant, replicate) pairs whose @20 is more than 10 points below their @8."""
    return sum(1 for (p, n, s), v in r.items() if n == 20 and (p, 8, s) in r and v < r[(p, 8, s)] - 10)


def pooled_rates(folders: list[Path], switch: str) -> dict[tuple, float]:  # type: ignore[type-arg]
    """One switch's rates over both sets and the given rounds' folders, keyed by set and cell."""
    return {(s, *k): v for folder in folders for s in SETS for k, v in rates(folder / f"{s}-{switch}").items()}


def analyse_combination(rnd: Round) -> None:
    """Amendment 3: the combination against the base, DART alone and the weighting alone, each
    pooled over the first two rounds' cells (the combination ran on all of them), by set and count
    as secondaries; then the decision rule's outcome."""
    earlier = [Round(n).here for n in (1, 2)]
    plus = pooled_rates([rnd.here], COMBINATION)
    summary: dict[str, object] = {}
    rows = ["| against | set | interactions | cells | other % | CoL+ % | CoL+ minus other, points [95 % CI] |",
            "| --- | --- | --- | ---: | ---: | ---: | --- |"]
    for other_name in COMBINED_WITH:
        other = pooled_rates(earlier, other_name)
        for set_name in (*SETS, None):
            for n in (8, 20, None):
                if set_name is None and n is not None:
                    continue
                res = paired(other, plus, lambda k, s=set_name, n=n: (s is None or k[0] == s) and (n is None or k[2] == n))
                key = f"{other_name}/{set_name or 'both'}/{n or 'both'}"
                summary[key] = res
                bold = "**" if set_name is None else ""
                rows.append(f"| {bold}{other_name}{bold} | {set_name or 'both'} | {n or '8 and 20'} | {res['cells']} | "
                            f"{res['base_pct']} | {res['switch_pct']} | {bold}{res['mean_diff_pts']:+} {res['ci95']}{bold} |")
    for set_name in SETS:
        summary[f"regressions/{set_name}"] = {
            w: regressions({k[1:]: v for k, v in pooled_rates(earlier if w != COMBINATION else [rnd.here], w).items()
                            if k[0] == set_name})
            for w in (*COMBINED_WITH, COMBINATION)}
    base, dart = summary["base/both/both"], summary["dart/both/both"]
    lower = base["ci95"][0] if base["ci95"] else None  # type: ignore[index]
    keep = lower is not None and lower > 0 and dart["mean_diff_pts"] >= 0  # type: ignore[index]
    summary["decision"] = ("CoL+ is the combination (DART with the weighting)" if keep
                           else "CoL+ is DART alone (the combination failed the rule)")
    rows.append(f"\nDecision (PLAN.md, amendment 3): {summary['decision']}.")
    (rnd.here / "summary.json").write_text(json.dumps(summary, indent=1) + "\n")
    (rnd.here / "table.md").write_text("\n".join(rows) + "\n")
    print("\n".join(rows))


def analyse_on_colplus(rnd: Round) -> None:
    """Amendments 4 and 5: each of the round's switches on top of CoL+ against the third round's CoL+ on
    the same 96 cells (the primary, both sets pooled), by set and count, and the regressions."""
    plus = pooled_rates([Round(3).here], COMBINATION)
    summary: dict[str, object] = {}
    rows = ["| switch on CoL+ | set | interactions | cells | CoL+ % | with the switch % | difference, points [95 % CI] |",
            "| --- | --- | --- | ---: | ---: | ---: | --- |"]
    for switch in ROUND_SWITCHES[rnd.number]:
        other = pooled_rates([rnd.here], switch)
        for set_name in (*SETS, None):
            for n in (8, 20, None):
                res = paired(plus, other, lambda k, s=set_name, n=n: (s is None or k[0] == s) and (n is None or k[2] == n))
                summary[f"{switch}/{set_name or 'both'}/{n or 'both'}"] = res
                bold = "**" if set_name is None and n is None else ""
                rows.append(f"| {bold}{switch}{bold} | {set_name or 'both'} | {n or '8 and 20'} | {res['cells']} | "
                            f"{res['base_pct']} | {res['switch_pct']} | {bold}{res['mean_diff_pts']:+} {res['ci95']}{bold} |")
        for set_name in SETS:
            summary[f"{switch}/{set_name}/regressions"] = {
                "colplus": regressions({k[1:]: v for k, v in plus.items() if k[0] == set_name}),
                "switch": regressions({k[1:]: v for k, v in other.items() if k[0] == set_name})}
        ci = summary[f"{switch}/both/both"]["ci95"]  # type: ignore[index]
        summary[f"{switch}/decision"] = ("supported: on top of CoL+" if ci is not None and ci[0] > 0 else
                                         "harmful: CoL+ stays as it is" if ci is not None and ci[1] < 0 else
                                         "not shown: CoL+ stays as it is")
        rows.append(f"\nDecision (PLAN.md, amendment {rnd.number}), {switch}: {summary[f'{switch}/decision']}.")
    (rnd.here / "summary.json").write_text(json.dumps(summary, indent=1) + "\n")
    (rnd.here / "table.md").write_text("\n".join(rows) + "\n")
    print("\n".join(rows))


def analyse(rnd: Round) -> None:
    """As PLAN.md fixes it: per switch against the round's base, by set and count, and pooled
    over both sets (the primary); a later round also pooled with the first (secondary)."""
    if COMBINATION in ROUND_SWITCHES[rnd.number]:
        return analyse_combination(rnd)
    if ROUND_CONDITIONS[rnd.number] == f'["{COMBINATION}"]':
        return analyse_on_colplus(rnd)
    summary: dict[str, object] = {}
    rows = ["| switch | set | interactions | cells | CoL % | switch % | difference, points [95 % CI] |",
            "| --- | --- | --- | ---: | ---: | ---: | --- |"]
    for switch in [w for w in ROUND_SWITCHES[rnd.number] if w != "base"]:
        missing = [f"{s}-{w}" for s in SETS for w in ("base", switch)
                   if not (rnd.here / f"{s}-{w}" / "results.jsonl").exists()]
        if missing:  # a switch is analysed once both its arms and their bases are in
            summary[f"{switch}/not_run"] = missing
            rows.append(f"| {switch} | not analysed: {', '.join(missing)} not in yet | | | | | |")
            continue
        for set_name in SETS:
            base, other = rates(rnd.here / f"{set_name}-base"), rates(rnd.here / f"{set_name}-{switch}")
            for n in (8, 20, None):
                res = paired(base, other, lambda k, n=n: n is None or k[1] == n)
                summary[f"{switch}/{set_name}/{n or 'both'}"] = res
                rows.append(f"| {switch} | {set_name} | {n or '8 and 20'} | {res['cells']} | {res['base_pct']} | "
                            f"{res['switch_pct']} | {res['mean_diff_pts']:+} {res['ci95']} |")
            summary[f"{switch}/{set_name}/regressions"] = {"base": regressions(base), "switch": regressions(other)}
        res = paired(pooled_rates([rnd.here], "base"), pooled_rates([rnd.here], switch), lambda k: True)
        summary[f"{switch}/pooled"] = res
        rows.append(f"| **{switch}** | **both** | 8 and 20 | {res['cells']} | {res['base_pct']} | {res['switch_pct']} | "
                    f"**{res['mean_diff_pts']:+} {res['ci95']}** |")
        if rnd.number > 1:
            both = [Round(n).here for n in range(1, rnd.number + 1)]
            res = paired(pooled_rates(both, "base"), pooled_rates(both, switch), lambda k: True)
            summary[f"{switch}/pooled_rounds_1_to_{rnd.number}"] = res
            rows.append(f"| {switch} | both, rounds 1-{rnd.number} | 8 and 20 | {res['cells']} | {res['base_pct']} | "
                        f"{res['switch_pct']} | {res['mean_diff_pts']:+} {res['ci95']} |")
    (rnd.here / "summary.json").write_text(json.dumps(summary, indent=1) + "\n")
    (rnd.here / "table.md").write_text("\n".join(rows) + "\n")
    print("\n".join(rows))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--round", type=int, default=1, choices=sorted(ROUND_SEEDS), help="the ablation's round (default 1)")
    parser.add_argument("step", choices=("configs", "code", "run", "collect", "analyse"))
    parser.add_argument("arms", nargs="*", help="some of the round's arms (default: all)")
    parser.add_argument("--commit", default="HEAD", help="code step: the commit to export")
    args = parser.parse_args()
    rnd = Round(args.round)
    arms = args.arms or rnd.arms
    if unknown := [a for a in arms if a not in rnd.arms]:
        parser.error(f"unknown arms {unknown}; round {rnd.number} has {rnd.arms}")
    {"configs": lambda: configs(rnd), "code": lambda: code(rnd, args.commit), "run": lambda: run(rnd, arms),
     "collect": lambda: collect(rnd, arms), "analyse": lambda: analyse(rnd)}[args.step]()


if __name__ == "__main__":
    sys.exit(main())
