"""The transfer table: the pinned grid's Demo@20 and CoL@20 policies (P1-P4 x replicates 0-1) on
our SITL, real ArduCopter SITL and real PX4 SIH, in still and disturbed air. The plan is
docs/camera.md, "The transfer table (preregistration)", written before any of these runs.
Steps, each resumable (what is kept is not run again):

    python results/transfer/run.py configs                 # the four config files (configs/)
    python results/transfer/run.py checkpoints             # retrain the 16 policies by --verify, keep their checkpoints
    python results/transfer/run.py fly ours still          # 16 policies x 20 episodes on one vehicle, in one air
    python results/transfer/run.py fly ardupilot disturbed # each policy on a freshly started autopilot, alone
    python results/transfer/run.py summarise               # summary.json and table.md from episodes/

Vehicles: ours (lockstep, its own camera, held-out starts from seed 100000), ardupilot (real
ArduCopter SITL at --speedup 5), px4 (real PX4 SIH at PX4_SIM_SPEED_FACTOR=4); the real ones
flown by the vehicle's clock with the camera drawn from their truth (--camera render, the
configs). Airs: still (level 0) and disturbed (level 0.2; on the real ones their own SITL's
wind where it has one, and the rendered pad's drive: docs/link.md). ``--policies KEY,...`` and
``--episodes N`` narrow a step for a check (a check's episodes go to runs/transfer/checks/).
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import subprocess
import sys
from pathlib import Path
from typing import Any

from colcommon.logged_run import run_logged

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
CONFIGS = HERE / "configs"
CHECKPOINTS = HERE / "checkpoints"
EPISODES = HERE / "episodes"
RUNS = ROOT / "runs" / "transfer"
PAPER_GRID = ROOT / "results" / "paper-grid"
POLICIES = tuple(f"{p}-{c}-20-s{r}" for c in ("demo", "col") for p in ("P1", "P2", "P3", "P4") for r in (0, 1))
VEHICLES = ("ours", "ardupilot", "px4")
ALIGNED = ("ardupilot-aligned", "px4-aligned")  # Amendment 1: the real ones with the policy's frame moved
COLUMNS = VEHICLES + ALIGNED
POLICY_PAD_NED_M = (0.0, 0.0, -1.5)  # where the pad was in the policies' world: our SITL's roof
AIRS = {"still": 0.0, "disturbed": 0.2}
SPEEDUP = {"ardupilot": 5.0, "px4": 4.0}
EPISODES_EACH, FIRST_SEED = 20, 100000

REAL_CONFIG = """# The transfer table (docs/camera.md, "The transfer table"): a real autopilot's SITL, {air} air.
[companion.session]
{frame}clock = "vehicle"  # the autopilots run faster than real time: steps by the vehicle's time_boot_ms
pad_ned_m = [0.0, 0.0, 0.0]  # the pad on the autopilot's own ground
start_height_above_pad_m = 8.0  # the start box of our SITL's resets
start_xy_range_m = 3.0
autopilot_sim_disturbance = {disturb}  # its own SITL's wind and the rendered pad's drive (docs/link.md)

[companion.perception]
camera = "render"  # drawn from the SITL's truth: what a camera on the vehicle would see

[sitl.world]
vehicle_height_m = 0.0

[sitl.disturbance]
level = {level}
"""


def autopilot_of(vehicle: str) -> str:
    return vehicle.removesuffix("-aligned")


def config_path(vehicle: str, air: str) -> Path:
    if vehicle == "ours":
        return CONFIGS / f"ours-{air}.toml"
    return CONFIGS / f"real-{air}{'-aligned' if vehicle in ALIGNED else ''}.toml"


def frame_line(aligned: bool) -> str:
    """Amendment 1's setting: the position the policy sees moved so the pad sits on the roof it learned on."""
    if not aligned:
        return ""
    return (f"policy_pad_ned_m = {list(POLICY_PAD_NED_M)}  # the pad where the policies learned it "
            "(our SITL's roof): docs/camera.md, \"The policy's frame\"\n")


def config_texts() -> dict[Path, str]:
    """Our SITL's: the pinned grid's own config with the air's level; the real autopilots': above."""
    grid = (PAPER_GRID / "config.toml").read_text()
    if "\nlevel = 0.2\n" not in grid:
        raise SystemExit(f"{PAPER_GRID / 'config.toml'}: no 'level = 0.2' line to set the air by")
    out = {}
    for air, level in AIRS.items():
        out[config_path("ours", air)] = (f"# The transfer table (docs/camera.md): our SITL, {air} air; the pinned grid's "
                                         "config otherwise.\n" + grid.replace("\nlevel = 0.2\n", f"\nlevel = {level}\n"))
        for vehicle in ("px4", "px4-aligned"):
            out[config_path(vehicle, air)] = REAL_CONFIG.format(air=air, level=level, disturb=str(level > 0).lower(),
                                                                frame=frame_line(vehicle in ALIGNED))
    return out


def write_configs() -> None:
    CONFIGS.mkdir(parents=True, exist_ok=True)
    for path, text in config_texts().items():
        path.write_text(text)
        print(f"wrote {path.relative_to(ROOT)}")
    step_record("configs")


def step_record(step: str, **context: object) -> None:
    """The step's own line in environment.jsonl: the commit its files came from and this
    process's environment (a retraining ran in the paper grid's recorded one, which
    ``--verify`` sets; its verdict's ``environment_differences`` says what differed)."""
    from colcommon.numeric_env import append_record

    append_record(HERE, step=step, command=["results/transfer/run.py", step], **context)


def col() -> str:
    return str(Path(sys.executable).with_name("col"))


# ----- the policies ---------------------------------------------------------------------------------

def checkpoints(keys: tuple[str, ...], runs: Path) -> None:
    """Retrain each policy by rerunning its committed trial with ``col experiment --verify`` (its
    line must come out byte for byte; the command sets the numeric environment the grid ran in),
    and keep its final checkpoint. The verdicts go to checkpoints.jsonl."""
    CHECKPOINTS.mkdir(parents=True, exist_ok=True)
    for key in keys:
        if (CHECKPOINTS / f"{key}.npz").exists():
            continue
        keep = runs / "retrain" / key
        shutil.rmtree(keep, ignore_errors=True)
        cmd = [col(), "experiment", "--verify", str(PAPER_GRID.relative_to(ROOT)), "--trial", key, "--keep", str(keep)]
        print(f"{key}: retraining ({' '.join(cmd[1:])})", flush=True)
        done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, stdin=subprocess.DEVNULL)
        (runs / f"retrain-{key}.log").write_text(done.stdout + done.stderr)
        verdict = json.loads(done.stdout.strip().splitlines()[-1]) if done.stdout.strip() else {}
        identical = done.returncode == 0 and verdict.get("identical") == 1
        with (HERE / "checkpoints.jsonl").open("a") as out:
            out.write(json.dumps({"trial": key, "identical": identical, "exit_code": done.returncode,
                                  "verdict": done.stdout.strip().splitlines()[0] if done.stdout.strip() else "",
                                  "environment_differences": verdict.get("environment_differences"),
                                  "command": " ".join(["col", *cmd[1:-1], f"runs/transfer/retrain/{key}"])}) + "\n")
        if not identical:
            print(f"{key}: NOT identical to its committed line (see {runs / f'retrain-{key}.log'}): not kept, not flown",
                  flush=True)
            continue
        final = next(json.loads(line)["final_checkpoint"] for line in (PAPER_GRID / "results.jsonl").read_text().splitlines()
                     if f'"key": "{key}"' in line)  # relative to the grid's folder: trials/KEY/...
        shutil.copyfile(keep / key / final, CHECKPOINTS / f"{key}.npz")
        print(f"{key}: identical; kept checkpoints/{key}.npz", flush=True)
    step_record("checkpoints", policies=list(keys),
                numeric_environment="the paper grid's recorded one (results/paper-grid/environment.jsonl), set by --verify")


# ----- flying -----------------------------------------------------------------------------------------

def kept_path(key: str, vehicle: str, air: str, episodes: int, runs: Path) -> Path:
    name = f"{key}-{vehicle}-{air}.jsonl"
    return EPISODES / name if episodes == EPISODES_EACH else runs / "checks" / f"{episodes}-{name}"


def fly(vehicle: str, air: str, keys: tuple[str, ...], episodes: int, runs: Path) -> None:
    for key in keys:
        kept = kept_path(key, vehicle, air, episodes, runs)
        checkpoint = CHECKPOINTS / f"{key}.npz"
        if kept.exists():
            continue
        if not checkpoint.exists():
            print(f"{key}: no checkpoint (run.py checkpoints first); skipped", flush=True)
            continue
        run_dir = runs / f"{key}-{vehicle}-{air}-{episodes}"
        shutil.rmtree(run_dir, ignore_errors=True)
        cmd = [col(), "eval", str(checkpoint), "--episodes", str(episodes), "--seed", str(FIRST_SEED),
               "--config", str(config_path(vehicle, air)), "--run-dir", str(run_dir)]
        log = runs / f"{key}-{vehicle}-{air}-{episodes}.log"
        if vehicle == "ours":
            run_logged(cmd, log, ROOT)
        else:
            fly_real(vehicle, cmd, log, runs / "autopilots" / f"{key}-{vehicle}-{air}")
        kept.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(run_dir / "episodes.jsonl", kept)
        if kept.parent == EPISODES:
            keep_eval_records(run_dir, key, vehicle, air)
        records = [json.loads(line) for line in kept.read_text().splitlines()]
        print(json.dumps({"policy": key, "vehicle": vehicle, "air": air, "episodes": len(records),
                          "on_pad": sum(bool(r["success"]) for r in records)}), flush=True)


def keep_eval_records(run_dir: Path, key: str, vehicle: str, air: str) -> None:
    """The evaluation's own environment records (``col eval`` writes them in its run folder, not
    committed) copied into this folder's environment.jsonl, tagged with what was flown."""
    from colcommon.numeric_env import RECORDS_NAME, read_records

    with (HERE / RECORDS_NAME).open("a") as out:
        for rec in read_records(run_dir):
            rec = {**rec, "step": "fly", "policy": key, "vehicle": vehicle, "air": air,
                   "command": ["col", "eval", f"checkpoints/{key}.npz", "--config", f"configs/{config_path(vehicle, air).name}"]}
            out.write(json.dumps(rec, sort_keys=True) + "\n")


def records(vehicle: str, air: str) -> None:
    """keep_eval_records for episodes flown before fly kept them itself (those not yet recorded)."""
    from colcommon.numeric_env import read_records

    done = {(r.get("policy"), r.get("vehicle"), r.get("air")) for r in read_records(HERE) if r.get("step") == "fly"}
    for key in POLICIES:
        run_dir = RUNS / f"{key}-{vehicle}-{air}-{EPISODES_EACH}"
        if (EPISODES / f"{key}-{vehicle}-{air}.jsonl").exists() and (key, vehicle, air) not in done and run_dir.is_dir():
            keep_eval_records(run_dir, key, vehicle, air)


def fly_real(vehicle: str, cmd: list[str], log: Path, work: Path) -> None:
    """``cmd`` against a freshly started autopilot of ``vehicle``, stopped afterwards."""
    from companion.testing.autopilots import find_autopilots, start_ardupilot, start_px4

    root, why = find_autopilots()
    if root is None:
        raise SystemExit(why)
    shutil.rmtree(work, ignore_errors=True)
    autopilot = autopilot_of(vehicle)
    start = start_px4 if autopilot == "px4" else start_ardupilot
    with start(root, work, speedup=SPEEDUP[autopilot]) as ap:
        run_logged(cmd + ["--connect", ap.connection], log, ROOT)


# ----- the table ----------------------------------------------------------------------------------------

def on_pad_pct(path: Path) -> float | None:
    if not path.exists():
        return None
    records = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    return 100.0 * sum(bool(r["success"]) for r in records) / len(records) if records else None


def summary() -> dict[str, Any]:
    """Per policy, vehicle and air the share on the pad; per vehicle, air and condition the mean
    transfer gap (vehicle minus ours, paired by policy) with a 95 % BCa interval over policies."""
    from companion.statistics import bootstrap_mean_ci

    shares = {f"{k}/{v}/{a}": on_pad_pct(EPISODES / f"{k}-{v}-{a}.jsonl") for k in POLICIES for v in COLUMNS for a in AIRS}
    gaps: dict[str, Any] = {}
    for vehicle in COLUMNS[1:]:
        for air in AIRS:
            for cond in ("demo", "col", "all"):
                keys = [k for k in POLICIES if cond == "all" or f"-{cond}-" in k]
                pairs = [(shares[f"{k}/{vehicle}/{air}"], shares[f"{k}/ours/{air}"]) for k in keys]
                diffs = [a - b for a, b in pairs if a is not None and b is not None]
                ci = bootstrap_mean_ci(diffs) if len(diffs) >= 2 else None
                gaps[f"{vehicle}/{air}/{cond}"] = {
                    "policies": len(diffs), "mean_gap_points": round(statistics.fmean(diffs), 2) if diffs else None,
                    "interval95": [round(x, 2) for x in ci] if ci else None}
    col_minus_demo: dict[str, Any] = {}
    for vehicle in COLUMNS:
        for air in AIRS:
            col_minus_demo[f"{vehicle}/{air}"] = paired_mean(
                [(shares[f"{k}/{vehicle}/{air}"], shares[f"{k.replace('-col-', '-demo-')}/{vehicle}/{air}"])
                 for k in POLICIES if "-col-" in k], bootstrap_mean_ci)
    frame_moved: dict[str, Any] = {}  # Amendment 1: aligned minus measured, the same policy on the same autopilot
    for vehicle in ALIGNED:
        for air in AIRS:
            for cond in ("demo", "col", "all"):
                keys = [k for k in POLICIES if cond == "all" or f"-{cond}-" in k]
                frame_moved[f"{vehicle}/{air}/{cond}"] = paired_mean(
                    [(shares[f"{k}/{vehicle}/{air}"], shares[f"{k}/{autopilot_of(vehicle)}/{air}"]) for k in keys],
                    bootstrap_mean_ci)
    return {"shares_pct": shares, "gaps": gaps, "col_minus_demo": col_minus_demo, "frame_moved": frame_moved,
            "plan": "docs/camera.md, The transfer table (preregistration)"}


def interval_rows(title: str, count: str, rows: dict[str, dict[str, Any]], count_key: str, mean_key: str) -> list[str]:
    """A markdown table of paired means with their 95 % intervals, one row per contrast."""
    out = ["", f"| {title} | {count} | mean, points | 95 % BCa |", "| --- | ---: | ---: | --- |"]
    for name, row in rows.items():
        mean, ci = row[mean_key], row["interval95"]
        out.append(f"| {name} | {row[count_key]} | {'-' if mean is None else mean} | "
                   f"{'-' if ci is None else f'[{ci[0]}, {ci[1]}]'} |")
    return out


def paired_mean(pairs: list[tuple[float | None, float | None]], ci_of: Any) -> dict[str, Any]:
    """The mean of a - b over the pairs where both were flown, with its 95 % interval."""
    diffs = [a - b for a, b in pairs if a is not None and b is not None]
    ci = ci_of(diffs) if len(diffs) >= 2 else None
    return {"pairs": len(diffs), "mean_points": round(statistics.fmean(diffs), 2) if diffs else None,
            "interval95": [round(x, 2) for x in ci] if ci else None}


def table(s: dict[str, Any]) -> str:
    lines = ["# The transfer table", "", "Made by `python results/transfer/run.py summarise` from `episodes/`; the plan is "
             "docs/camera.md, \"The transfer table (preregistration)\". On the pad by truth, % of 20 episodes.", "",
             "| policy | " + " | ".join(f"{v}, {a}" for a in AIRS for v in COLUMNS) + " |",
             "| --- |" + " ---: |" * (len(AIRS) * len(COLUMNS))]
    for key in POLICIES:
        cells = [s["shares_pct"][f"{key}/{v}/{a}"] for a in AIRS for v in COLUMNS]
        lines.append(f"| {key} | " + " | ".join("-" if c is None else f"{c:.0f}" for c in cells) + " |")
    lines += interval_rows("gap: vehicle - ours, paired by policy", "policies", s["gaps"], "policies", "mean_gap_points")
    lines += interval_rows("CoL@20 - Demo@20, paired by participant and replicate", "pairs", s["col_minus_demo"],
                           "pairs", "mean_points")
    lines += interval_rows("frame moved - measured, the same policy (Amendment 1)", "pairs", s["frame_moved"],
                           "pairs", "mean_points")
    return "\n".join(lines) + "\n"


def summarise() -> None:
    s = summary()
    write_summary(HERE, s, table(s), sum(v is not None for v in s["shares_pct"].values()), len(s["shares_pct"]))


def write_summary(folder: Path, s: dict[str, Any], table_text: str, flown: int, planned: int) -> None:
    """summary.json and table.md into ``folder``, and a line saying how much of the plan they hold."""
    (folder / "summary.json").write_text(json.dumps(s, indent=1) + "\n")
    (folder / "table.md").write_text(table_text)
    print(json.dumps({"written": ["summary.json", "table.md"], "flown": flown, "planned": planned}))


def parse_keys(text: str | None) -> tuple[str, ...]:
    if not text:
        return POLICIES
    keys = tuple(k.strip() for k in text.split(",") if k.strip())
    unknown = [k for k in keys if k not in POLICIES]
    if unknown:
        raise SystemExit(f"unknown policies {unknown}; the plan's are {', '.join(POLICIES)}")
    return keys


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=Path, default=RUNS, help="where run folders and logs go")
    sub = parser.add_subparsers(dest="step", required=True)
    sub.add_parser("configs", help="the config files")
    p = sub.add_parser("checkpoints", help="retrain the policies by --verify and keep their checkpoints")
    p.add_argument("--policies", help="KEY,... (default: the plan's 16)")
    p = sub.add_parser("fly", help="the policies on one vehicle in one air")
    p.add_argument("vehicle", choices=COLUMNS)
    p.add_argument("air", choices=tuple(AIRS))
    p.add_argument("--policies", help="KEY,... (default: the plan's 16)")
    p.add_argument("--episodes", type=int, default=EPISODES_EACH, help="a check with fewer goes to runs/transfer/checks/")
    p = sub.add_parser("records", help="copy flown evaluations' environment records into environment.jsonl")
    p.add_argument("vehicle", choices=COLUMNS)
    p.add_argument("air", choices=tuple(AIRS))
    sub.add_parser("summarise", help="summary.json and table.md")
    args = parser.parse_args()
    if args.step == "configs":
        write_configs()
    elif args.step == "checkpoints":
        checkpoints(parse_keys(args.policies), args.runs)
    elif args.step == "fly":
        if args.episodes < 1:
            raise SystemExit("--episodes must be at least 1")
        fly(args.vehicle, args.air, parse_keys(args.policies), args.episodes, args.runs)
    elif args.step == "records":
        records(args.vehicle, args.air)
    else:
        summarise()


if __name__ == "__main__":
    try:
        main()
    except subprocess.CalledProcessError as exc:
        raise SystemExit(str(exc)) from exc
