"""The learner switches' ablation (issue: the learner reaches its teacher), preregistered in
results/learner-ablation/PLAN.md before any of its runs. Steps, from the repository's root, each
resumable (`col experiment` resumes a results folder; a finished arm is skipped):

    python results/learner-ablation/run.py configs            # write each arm's experiment file
    python results/learner-ablation/run.py code [--commit C]  # the library the runs use: HEAD, exported
    python results/learner-ablation/run.py run [ARM ...]      # col experiment per arm (runs/learner-ablation/)
    python results/learner-ablation/run.py collect [ARM ...]  # per trial and per start into results/learner-ablation/
    python results/learner-ablation/run.py analyse            # summary.json and table.md, as PLAN.md says

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
import shutil
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
}
"""Each switch's settings, fixed in PLAN.md before the runs (the rest at their defaults)."""
EXPERIMENT = {"conditions": '["col"]', "interactions": "[8, 20]", "seeds": "[0, 1]",
              "eval_runs": "50", "eval_seed": "600000"}
ARMS = [f"{s}-{w}" for s in SETS for w in SWITCHES]
BOOT_SEED = 0


def toml_value(v: object) -> str:
    return "true" if v is True else "false" if v is False else json.dumps(v)


def arm_config(arm: str) -> str:
    """The set's experiment file with the ablation's [experiment] and the switch's learner keys."""
    set_name, switch = arm.split("-", 1) if not arm.startswith("human-like") else ("human-like", arm[11:])
    source, people = SETS[set_name]
    text = (ROOT / source).read_text()
    values = {**EXPERIMENT, "participants": json.dumps(people)}
    for key, value in values.items():
        text, n = re.subn(rf"^{key} = .*$", f"{key} = {value}", text, count=1, flags=re.M)
        if n != 1:
            raise SystemExit(f"{source}: no '{key} =' line in [experiment]")
    keys = "".join(f"{k} = {toml_value(v)}\n" for k, v in SWITCHES[switch].items())
    text, n = re.subn(r'^\[companion\.learner\]\nmode = "budgeted"\n', lambda m: m.group(0) + keys, text,
                      count=1, flags=re.M)
    if n != 1:
        raise SystemExit(f"{source}: no [companion.learner] table with mode = \"budgeted\"")
    header = f"# The learner ablation's arm {arm} (results/learner-ablation/PLAN.md), made from {source}\n"
    return header + text


def configs() -> None:
    for arm in ARMS:
        path = HERE / "configs" / f"{arm}.toml"
        path.parent.mkdir(exist_ok=True)
        path.write_text(arm_config(arm))
        print(path.relative_to(ROOT))


def code(commit: str = "HEAD") -> None:
    """runs/learner-ablation/code/: the repository at ``commit`` as committed (a later session
    continues with the commit the first arms ran at, RUN.md)."""
    if (CODE / "COMMIT").exists():
        print(f"runs/learner-ablation/code holds {(CODE / 'COMMIT').read_text().strip()} already")
        return
    shutil.rmtree(CODE, ignore_errors=True)
    CODE.mkdir(parents=True)
    head = subprocess.run(["git", "rev-parse", commit], cwd=ROOT, capture_output=True, text=True,
                          check=True).stdout.strip()
    archive = subprocess.run(["git", "archive", head], cwd=ROOT, capture_output=True, check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(CODE)], input=archive, check=True)
    (CODE / "COMMIT").write_text(head + "\n")
    print(f"runs/learner-ablation/code: {head}")


def run(arms: list[str]) -> None:
    """``col experiment`` per arm, from inside the export (its configs are the committed ones)."""
    if not (CODE / "COMMIT").exists():
        raise SystemExit("no exported library: run the 'code' step first")
    for arm in arms:
        cmd = [str(ROOT / ".venv/bin/col"), "experiment", "--config", f"results/learner-ablation/configs/{arm}.toml",
               "--workers", "2", "--out", str(RUNS / arm)]
        print(" ".join(cmd), flush=True)
        subprocess.run(cmd, check=True, cwd=CODE, env={**os.environ, "PYTHONPATH": str(CODE)})


def collect(arms: list[str]) -> None:
    """Each arm's trial lines, environment and timings, and one line per validation start."""
    for arm in arms:
        src, dst = RUNS / arm, HERE / arm
        dst.mkdir(exist_ok=True)
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
        gather_environments()
        print(dst.relative_to(ROOT), len(lines), "starts")


def gather_environments() -> None:
    """The arms' environment records, each once, in this folder's environment.jsonl (what every
    committed results folder has), marked with their arm."""
    records = []
    for arm in ARMS:
        path = HERE / arm / "environment.jsonl"
        if path.exists():
            records += [json.dumps({"arm": arm, **json.loads(line)}, sort_keys=True)
                        for line in path.read_text().splitlines() if line.strip()]
    (HERE / "environment.jsonl").write_text("\n".join(records) + "\n")


def rates(arm: str) -> dict[tuple[str, int, int], float]:
    """Validation success (%) per (participant, interactions, replicate)."""
    out = {}
    for line in (HERE / arm / "results.jsonl").read_text().splitlines():
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


def analyse() -> None:
    summary: dict[str, object] = {}
    rows = ["| switch | set | interactions | cells | CoL % | switch % | difference, points [95 % CI] |",
            "| --- | --- | --- | ---: | ---: | ---: | --- |"]
    for switch in [w for w in SWITCHES if w != "base"]:
        missing = [f"{s}-{w}" for s in SETS for w in ("base", switch) if not (HERE / f"{s}-{w}" / "results.jsonl").exists()]
        if missing:  # a switch is analysed once both its arms and their bases are in
            summary[f"{switch}/not_run"] = missing
            rows.append(f"| {switch} | not analysed: {', '.join(missing)} not in yet | | | | | |")
            continue
        for set_name in SETS:
            base, other = rates(f"{set_name}-base"), rates(f"{set_name}-{switch}")
            for n in (8, 20, None):
                res = paired(base, other, lambda k, n=n: n is None or k[1] == n)
                summary[f"{switch}/{set_name}/{n or 'both'}"] = res
                rows.append(f"| {switch} | {set_name} | {n or '8 and 20'} | {res['cells']} | {res['base_pct']} | "
                            f"{res['switch_pct']} | {res['mean_diff_pts']:+} {res['ci95']} |")
            summary[f"{switch}/{set_name}/regressions"] = {"base": regressions(base), "switch": regressions(other)}
        pooled_base = {(s, *k): v for s in SETS for k, v in rates(f"{s}-base").items()}
        pooled = {(s, *k): v for s in SETS for k, v in rates(f"{s}-{switch}").items()}
        res = paired(pooled_base, pooled, lambda k: True)
        summary[f"{switch}/pooled"] = res
        rows.append(f"| **{switch}** | **both** | 8 and 20 | {res['cells']} | {res['base_pct']} | {res['switch_pct']} | "
                    f"**{res['mean_diff_pts']:+} {res['ci95']}** |")
    (HERE / "summary.json").write_text(json.dumps(summary, indent=1) + "\n")
    (HERE / "table.md").write_text("\n".join(rows) + "\n")
    print("\n".join(rows))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("step", choices=("configs", "code", "run", "collect", "analyse"))
    parser.add_argument("arms", nargs="*", help=f"some of {ARMS} (default: all)")
    parser.add_argument("--commit", default="HEAD", help="code step: the commit to export")
    args = parser.parse_args()
    arms = args.arms or ARMS
    if unknown := [a for a in arms if a not in ARMS]:
        parser.error(f"unknown arms {unknown}; use some of {ARMS}")
    {"configs": lambda: configs(), "code": lambda: code(args.commit), "run": lambda: run(arms), "collect": lambda: collect(arms),
     "analyse": lambda: analyse()}[args.step]()


if __name__ == "__main__":
    sys.exit(main())
