"""CoL on the target vehicle: a CoL@20 policy from our SITL continued on real PX4 SIH by the same
synthetic participant, intervening (int) or demonstrating (demo) for 2, 4 and 8 more episodes,
each checkpoint flown alone on the transfer table's 20 held-out starts. The plan is
docs/camera.md, "CoL on the target vehicle (preregistration)", written before any of these runs.
Steps, each resumable (what is kept is not run again):

    python results/transfer/oncraft.py configs               # configs/oncraft-s0.toml (the trial's learner on PX4 SIH)
    python results/transfer/oncraft.py base P1-col-20-s0     # the trial's run folder again (col experiment --verify --keep)
    python results/transfer/oncraft.py fly P1-col-20-s0 int  # 2 + 2 + 4 episodes on fresh PX4 SIHs, each checkpoint evaluated
    python results/transfer/oncraft.py summarise             # oncraft/summary.json and oncraft/table.md

Kept in oncraft/: base.jsonl (each rerun's verdict and its final weights' SHA-256),
train/KEY-ARM.jsonl (the continued episodes' records), checkpoints/KEY-ARM-N.npz,
episodes/KEY-ARM-N-px4-still.jsonl (the evaluations). Run folders and logs go to
runs/transfer/oncraft/ (not committed).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import shutil
import statistics
import subprocess
from pathlib import Path
from typing import Any

from colcommon.script_module import load_script

transfer = load_script(Path(__file__).resolve().parent / "run.py", "transfer_run")  # this folder's run.py

HERE = transfer.HERE
OUT = HERE / "oncraft"
RUNS = transfer.RUNS / "oncraft"
POLICIES = tuple(f"{p}-col-20-s0" for p in ("P1", "P2", "P3", "P4"))
ARMS = ("int", "demo", "int-drift", "demo-drift")
"""int / demo: the participant as in the grid. The -drift arms (the plan's Amendment 2): the same
participant, whose expert judges the drift PX4 SIH's velocity estimate does not show from the
picture ([companion.pilot] set_down_by_picture and judge_drift_by_picture; configs/oncraft-s0-drift.toml)."""
PAIRS = (("int", "demo"), ("int-drift", "demo-drift"))
DRIFT_PILOT = "\n[companion.pilot]  # Amendment 2: the participant judges the drift from the picture\nset_down_by_picture = true\njudge_drift_by_picture = true\n"
SITTINGS = (2, 2, 4)  # episodes per freshly started PX4 SIH; checkpoints after 2, 4 and 8
FIRST_CONTINUED = 20  # the trial flew episodes 0-19
VEHICLE, AIR = "px4-aligned", "still"  # PX4 SIH, the policy's frame moved (the plan's Amendment 1)
UPDATES_PER_STEP = 40  # the pinned grid's budgeted learner (results/paper-grid/config.toml)


def replicate(key: str) -> int:
    return int(key.rsplit("-s", 1)[1])


def config_path(rep: int, drift: bool = False) -> Path:
    return transfer.CONFIGS / f"oncraft-s{rep}{'-drift' if drift else ''}.toml"


def condition(arm: str) -> str:
    """The arm's --condition: int or demo."""
    return arm.split("-")[0]


def drift_arm(arm: str) -> bool:
    return arm.endswith("-drift")


def config_text(rep: int, drift: bool = False) -> str:
    """The transfer table's PX4 config (still air) with the grid trial's learner and seeds, so
    the continued episodes learn as the trial did and start from its training seeds 20, 21, ..."""
    seed = 1000 * rep  # companion.experiment.grid.START_SEEDS_PER_REPLICATE
    real = transfer.REAL_CONFIG.format(air=AIR, level=0.0, disturb="false", frame=transfer.frame_line(True))
    real = real.replace("[companion.session]\n", f"[companion.session]\nseed = {seed}  # the trial's: episode i starts from seed + i\n", 1)
    return (f"# CoL on the target vehicle (docs/camera.md): PX4 SIH, still air, replicate {rep}'s learner.\n"
            + real.split("\n", 1)[1]
            + f"\n[companion.learner]\nmode = \"budgeted\"  # the grid's: updates tied to control steps\n"
              f"updates_per_step = {UPDATES_PER_STEP}\nseed = {seed}\n"
            + (DRIFT_PILOT if drift else ""))


def write_configs() -> None:
    for rep in (0,):
        for drift in (False, True):
            config_path(rep, drift).write_text(config_text(rep, drift))
            print(f"wrote {config_path(rep, drift).relative_to(transfer.ROOT)}")
    from colcommon.numeric_env import append_record

    append_record(HERE, step="oncraft-configs", command=["results/transfer/oncraft.py", "configs"])


# ----- the trial's run folder ----------------------------------------------------------------------

def weights_sha256(path: Path) -> str:
    """The checkpoint's arrays (weights, biases, normalisation), not its metadata: that holds the
    time the file was written, which a rerun cannot repeat."""
    import numpy as np

    with np.load(path, allow_pickle=False) as npz:
        digest = hashlib.sha256()
        for name in sorted(n for n in npz.files if n != "metadata"):
            digest.update(name.encode() + npz[name].tobytes())
    return digest.hexdigest()


def base_dir(key: str) -> Path:
    return RUNS / "base" / key / key / "trials" / key / "train"


def base(key: str) -> bool:
    """Rerun the trial with ``--verify --keep``; True when its line came out byte for byte and its
    final checkpoint is the transfer table's. The verdict goes to base.jsonl."""
    folder = base_dir(key)
    kept = folder / "checkpoints" / f"episode_{FIRST_CONTINUED - 1:03d}.npz"
    if kept.exists() and weights_sha256(kept) == weights_sha256(transfer.CHECKPOINTS / f"{key}.npz"):
        return True  # rerun before, and its final policy is the transfer table's
    keep = RUNS / "base" / key
    shutil.rmtree(keep, ignore_errors=True)
    cmd = [transfer.col(), "experiment", "--verify", "results/paper-grid", "--trial", key, "--keep", str(keep)]
    print(f"{key}: rerunning its trial ({' '.join(cmd[1:])})", flush=True)
    done = subprocess.run(cmd, cwd=transfer.ROOT, capture_output=True, text=True, stdin=subprocess.DEVNULL)
    (RUNS / f"base-{key}.log").write_text(done.stdout + done.stderr)
    verdict = json.loads(done.stdout.strip().splitlines()[-1]) if done.stdout.strip() else {}
    final = folder / "checkpoints" / f"episode_{FIRST_CONTINUED - 1:03d}.npz"
    same = final.exists() and weights_sha256(final) == weights_sha256(transfer.CHECKPOINTS / f"{key}.npz")
    ok = done.returncode == 0 and verdict.get("identical") == 1 and same
    OUT.mkdir(parents=True, exist_ok=True)
    with (OUT / "base.jsonl").open("a") as out:
        out.write(json.dumps({"trial": key, "identical": verdict.get("identical") == 1, "exit_code": done.returncode,
                              "final_weights_sha256": weights_sha256(final) if final.exists() else None,
                              "same_as_transfer_checkpoint": same,
                              "command": f"col experiment --verify results/paper-grid --trial {key} --keep runs/transfer/oncraft/base/{key}"})
                  + "\n")
    if not ok:
        print(f"{key}: the rerun is not the committed trial (see {RUNS / f'base-{key}.log'}): not flown", flush=True)
    shutil.rmtree(keep / key / "trials" / key / "eval", ignore_errors=True)
    return ok


# ----- flying -------------------------------------------------------------------------------------

def arm_dir(key: str, arm: str) -> Path:
    return RUNS / f"{key}-{arm}"


def checkpoint_after(key: str, arm: str, n: int) -> Path:
    return OUT / "checkpoints" / f"{key}-{arm}-{n}.npz"


def eval_path(key: str, arm: str, n: int) -> Path:
    return OUT / "episodes" / f"{key}-{arm}-{n}-{VEHICLE}-{AIR}.jsonl"


def on_fresh_px4(cmd: list[str], log: Path, work: str) -> None:
    transfer.fly_real(VEHICLE, cmd, log, RUNS / "autopilots" / work)


def sitting(key: str, arm: str, done_before: int, episodes: int) -> None:
    """``episodes`` more of the arm's episodes on a freshly started PX4 SIH, continuing its folder."""
    folder = arm_dir(key, arm)
    if not folder.exists():
        shutil.copytree(base_dir(key), folder)
    first = FIRST_CONTINUED + done_before
    stale = [p for p in (folder / "checkpoints").glob("episode_*.npz") if int(p.stem[8:]) >= first]
    if stale:  # a sitting cut short: its episodes are flown again from the sitting's start
        raise SystemExit(f"{folder}: holds episodes from {first} on from a sitting cut short; "
                         f"remove the folder to start {key} {arm} again")
    cmd = [transfer.col(), "fly", "--pilot", f"synthetic:{key.split('-')[0]}", "--condition", condition(arm),
           "--episodes", str(episodes), "--config", str(config_path(replicate(key), drift_arm(arm))), "--run-dir", str(folder),
           "--no-pictures"]
    print(f"{key} {arm}: episodes {first}-{first + episodes - 1}", flush=True)
    on_fresh_px4(cmd, RUNS / f"{key}-{arm}-{first}.log", f"{key}-{arm}-{first}")


def evaluate(key: str, arm: str, n: int) -> None:
    """The checkpoint after ``n`` continued episodes, alone on the held-out starts, as the transfer table flies."""
    kept = eval_path(key, arm, n)
    if kept.exists():
        return
    run_dir = RUNS / f"eval-{key}-{arm}-{n}"
    shutil.rmtree(run_dir, ignore_errors=True)
    cmd = [transfer.col(), "eval", str(checkpoint_after(key, arm, n)), "--episodes", str(transfer.EPISODES_EACH),
           "--seed", str(transfer.FIRST_SEED), "--config", str(transfer.config_path(VEHICLE, AIR)),
           "--run-dir", str(run_dir), "--no-pictures"]
    on_fresh_px4(cmd, RUNS / f"eval-{key}-{arm}-{n}.log", f"eval-{key}-{arm}-{n}")
    kept.parent.mkdir(parents=True, exist_ok=True)
    shutil.copyfile(run_dir / "episodes.jsonl", kept)
    keep_records(run_dir, key, arm, n)
    records = read_jsonl(kept)
    print(json.dumps({"policy": key, "arm": arm, "after": n, "episodes": len(records),
                      "on_pad": sum(bool(r["success"]) for r in records)}), flush=True)


def keep_records(run_dir: Path, key: str, arm: str, n: int) -> None:
    """The evaluation's environment records, tagged, in the transfer folder's environment.jsonl."""
    from colcommon.numeric_env import RECORDS_NAME, read_records

    with (HERE / RECORDS_NAME).open("a") as out:
        for rec in read_records(run_dir):
            rec = {**rec, "step": "oncraft", "policy": key, "arm": arm, "after": n,
                   "command": ["col", "eval", f"oncraft/checkpoints/{key}-{arm}-{n}.npz", "--config",
                               f"configs/{transfer.config_path(VEHICLE, AIR).name}"]}
            out.write(json.dumps(rec, sort_keys=True) + "\n")


def fly(key: str, arm: str) -> None:
    """The arm's three sittings, each followed by its checkpoint's evaluation; resumes."""
    if not base(key):
        return
    done = 0
    for episodes in SITTINGS:
        n = done + episodes
        if not checkpoint_after(key, arm, n).exists():
            sitting(key, arm, done, episodes)
            last = arm_dir(key, arm) / "checkpoints" / f"episode_{FIRST_CONTINUED + n - 1:03d}.npz"
            if not last.exists():
                raise SystemExit(f"{key} {arm}: no {last.name} after the sitting; see its log in {RUNS}")
            checkpoint_after(key, arm, n).parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(last, checkpoint_after(key, arm, n))
            keep_training(key, arm)
        evaluate(key, arm, n)
        done = n


def keep_training(key: str, arm: str) -> None:
    """The continued episodes' records (episode >= 20) from the arm's folder."""
    records = [r for r in read_jsonl(arm_dir(key, arm) / "episodes.jsonl") if r.get("episode", -1) >= FIRST_CONTINUED]
    path = OUT / "train" / f"{key}-{arm}.jsonl"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("".join(json.dumps(r) + "\n" for r in records))


def read_jsonl(path: Path) -> list[dict[str, Any]]:
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()] if path.exists() else []


# ----- the table ----------------------------------------------------------------------------------

def cell(records: list[dict[str, Any]]) -> dict[str, Any] | None:
    from companion.statistics import wilson_interval

    if not records:
        return None
    hits = sum(bool(r["success"]) for r in records)
    lo, hi = wilson_interval(hits, len(records))
    dist = [r["true_touchdown_distance_m"] for r in records if r.get("true_touchdown_distance_m") is not None]
    return {"on_pad": hits, "episodes": len(records), "pct": round(100 * hits / len(records), 1),
            "wilson95_pct": [round(100 * lo, 1), round(100 * hi, 1)],
            "true_distance_median_m": round(statistics.median(dist), 3) if dist else None}


def summary() -> dict[str, Any]:
    cells: dict[str, Any] = {}
    for key in POLICIES:
        cells[f"{key}/before"] = cell(read_jsonl(transfer.EPISODES / f"{key}-{VEHICLE}-{AIR}.jsonl"))
        for arm in ARMS:
            for n in (2, 4, 8):
                cells[f"{key}/{arm}/{n}"] = cell(read_jsonl(eval_path(key, arm, n)))
    contrasts: dict[str, Any] = {}
    for n in (2, 4, 8):
        for arm, other_arm in PAIRS:
            for name, other in ((f"{arm}-{other_arm}", other_arm), (f"{arm}-before", None)):
                contrasts[f"{name}/{n}"] = contrast(cells, arm, other, n)
    return {"cells": cells, "contrasts": contrasts, "plan": "docs/camera.md, CoL on the target vehicle (preregistration)"}


MIN_POLICIES_FOR_INTERVAL = 3


def contrast(cells: dict[str, Any], arm: str, other: str | None, n: int) -> dict[str, Any]:
    """``arm`` after ``n`` minus ``other`` after ``n`` (or before), paired by policy."""
    from companion.statistics import bootstrap_mean_ci

    diffs = []
    for key in POLICIES:
        a = cells[f"{key}/{arm}/{n}"]
        b = cells[f"{key}/before"] if other is None else cells[f"{key}/{other}/{n}"]
        if a and b:
            diffs.append(a["pct"] - b["pct"])
    # A bootstrap over two policies only resamples their two values: its "interval" is their range.
    ci = bootstrap_mean_ci(diffs) if len(diffs) >= MIN_POLICIES_FOR_INTERVAL else None
    return {"policies": len(diffs), "mean_points": round(statistics.fmean(diffs), 2) if diffs else None,
            "interval95": [round(x, 2) for x in ci] if ci else None}


def table(s: dict[str, Any]) -> str:
    def show(c: dict[str, Any] | None) -> str:
        if c is None:
            return "-"
        lo, hi = c["wilson95_pct"]
        return f"{c['on_pad']}/{c['episodes']} [{lo:.0f}-{hi:.0f} %], {c['true_distance_median_m']} m"

    lines = ["# CoL on the target vehicle (PX4 SIH)", "",
             "Made by `python results/transfer/oncraft.py summarise`; the plan is docs/camera.md, \"CoL on the target "
             "vehicle (preregistration)\". On the pad by truth of 20 held-out starts, 95 % Wilson interval, median "
             f"true touchdown distance. The contrasts' intervals are drawn from {MIN_POLICIES_FOR_INTERVAL} policies on.", "",
             ]
    for pair in PAIRS:
        if pair != PAIRS[0]:
            lines += ["", "The plan's Amendment 2: the participant judges the drift from the picture.", ""]
        lines += ["| policy | before | " + " | ".join(f"{arm} after {n}" for arm in pair for n in (2, 4, 8)) + " |",
                  "| --- | --- | --- | --- | --- | --- | --- | --- |"]
        for key in POLICIES:
            cols = [s["cells"][f"{key}/before"]] + [s["cells"][f"{key}/{arm}/{n}"] for arm in pair for n in (2, 4, 8)]
            lines.append(f"| {key} | " + " | ".join(show(c) for c in cols) + " |")
    lines += transfer.interval_rows("contrast, paired by policy", "policies", s["contrasts"], "policies", "mean_points")
    return "\n".join(lines) + "\n"


def summarise() -> None:
    s = summary()
    OUT.mkdir(parents=True, exist_ok=True)
    (OUT / "summary.json").write_text(json.dumps(s, indent=1) + "\n")
    (OUT / "table.md").write_text(table(s))
    print(json.dumps({"written": ["oncraft/summary.json", "oncraft/table.md"],
                      "evaluated": sum(v is not None for k, v in s["cells"].items() if not k.endswith("/before"))}))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="step", required=True)
    sub.add_parser("configs", help="the on-craft config file")
    p = sub.add_parser("base", help="rerun a trial to get its run folder back")
    p.add_argument("policy", choices=POLICIES)
    p = sub.add_parser("fly", help="one arm's sittings and evaluations")
    p.add_argument("policy", choices=POLICIES)
    p.add_argument("arm", choices=ARMS)
    sub.add_parser("summarise", help="oncraft/summary.json and oncraft/table.md")
    args = parser.parse_args()
    RUNS.mkdir(parents=True, exist_ok=True)
    if args.step == "configs":
        write_configs()
    elif args.step == "base":
        if not base(args.policy):
            raise SystemExit(1)
    elif args.step == "fly":
        fly(args.policy, args.arm)
    else:
        summarise()


if __name__ == "__main__":
    main()
