"""The operator's baseline against the learned policies: the autopilot's own precision landing,
the scripted expert and the CoL@20 / Demo@20 policies on the experiment's held-out starts.
The plan (arms, levels, endpoints, analysis) is docs/baselines.md, "The operator's baseline",
written before these runs. Steps, each resumable on its own (a step whose output exists is skipped):

    python results/precland/compare/run.py configs              # the task's config files, from configs/paper.toml
    python results/precland/compare/run.py fly precland-px4 0.2 # one arm at one level (also precland-ardupilot, expert; 0)
    python results/precland/compare/run.py policies [--grid-run runs/paper-grid-pinned]
                                                                # CoL@20 / Demo@20 of P1-P4 replicate 0, then level 0
    python results/precland/compare/run.py real precland        # real PX4 SIH, rendered camera (also: real expert)
    python results/precland/compare/run.py records              # environment.jsonl from the runs' records
    python results/precland/compare/run.py summarise            # summary.json and table.md from the episodes

Run folders go to runs/precland-compare/; what is committed is each arm's episodes.jsonl (in
episodes/), the rerun policies' result lines (policies.jsonl) and the summaries.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from colcommon.logged_run import run_logged

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[2]
RUNS = ROOT / "runs" / "precland-compare"
EPISODES = HERE / "episodes"
CONFIGS = HERE / "configs"
GRID = ROOT / "results" / "paper-grid"  # made as results/paper-grid-pinned
LEVELS = ("0.2", "0")
STARTS, FIRST_START = 100, 100_000
REAL_STARTS = 20
PARTICIPANTS = ("P1", "P2", "P3", "P4")
POLICIES = tuple(f"{p}-{c}-20-s0" for c in ("col", "demo") for p in PARTICIPANTS)
ARMS = ("precland-px4", "precland-ardupilot", "expert")

ARUCO = '\n[sitl.camera]\npad_marker = "aruco"  # the ArUco board on the pad (sitl/pad_marker.py)\n'
ARDUPILOT = '\n[sitl.personality]\nautopilot = "ardupilot"\n'
REAL = """# Real PX4 SIH: the pad world rendered from its telemetry, the pad on its own ground; the
# experiment's start geometry and episode length (configs/default.toml), no disturbance.
[companion.session]
pad_ned_m = [0.0, 0.0, 0.0]

[companion.perception]
camera = "render"

[sitl.world]
vehicle_height_m = 0.0
"""


def col() -> str:
    return _rel(Path(sys.executable).with_name("col"))


def _rel(path: Path) -> str:
    """A path as the commands (run from the repository's root) name it: relative, so the
    records say nothing of the machine's folders."""
    return os.path.relpath(path, ROOT)


def config_name(arm: str, level: str) -> Path:
    kind = {"precland-px4": "precland-px4", "precland-ardupilot": "precland-ardupilot"}.get(arm, "colour-pad")
    return CONFIGS / f"{kind}-level-{level}.toml"


def write_configs() -> None:
    """configs/paper.toml at level 0.2 and 0, with the board (and the ArduPilot personality)."""
    paper = (ROOT / "configs" / "paper.toml").read_text()
    assert paper.count("level = 0.2") == 1, "configs/paper.toml's disturbance level moved"
    CONFIGS.mkdir(parents=True, exist_ok=True)
    for level in LEVELS:
        base = paper if level == "0.2" else paper.replace("level = 0.2", "level = 0.0")
        config_name("expert", level).write_text(base)
        config_name("precland-px4", level).write_text(base + ARUCO)
        config_name("precland-ardupilot", level).write_text(base + ARUCO + ARDUPILOT)
    (CONFIGS / "real-px4.toml").write_text(REAL + ARUCO)  # precision landing: the board on the pad
    (CONFIGS / "real-px4-colour-pad.toml").write_text(REAL)  # the expert: the colour pad its detector knows


def _run(cmd: list[str], log: Path) -> None:
    run_logged(cmd, log, ROOT)


def _keep(run_dir: Path, name: str) -> None:
    EPISODES.mkdir(parents=True, exist_ok=True)
    shutil.copy(run_dir / "episodes.jsonl", EPISODES / f"{name}.jsonl")


def environment_records() -> None:
    """``environment.jsonl`` here: every kept arm's run records (tagged with the arm), its
    folders named relative to the repository."""
    lines = []
    for kept in sorted(EPISODES.glob("*.jsonl")):
        records = RUNS / kept.stem / "environment.jsonl"
        if not records.exists():  # the level-0.2 policies: their grid's own records
            continue
        for line in records.read_text().splitlines():
            if line.strip():
                text = json.dumps({"arm": kept.stem, **json.loads(line)}, sort_keys=True)
                text = text.replace(str(ROOT) + os.sep, "")
                lines.append(re.sub(r'"[^"]*?(runs/paper-grid-pinned/)', r'"\1', text))  # the grid's run folder, wherever it ran
    (HERE / "environment.jsonl").write_text("\n".join(lines) + "\n")


def fly(arm: str, level: str) -> None:
    name = f"{arm}-level-{level}"
    if (EPISODES / f"{name}.jsonl").exists():
        return
    run_dir = RUNS / name
    shutil.rmtree(run_dir, ignore_errors=True)
    pilot = ["--pilot", "expert", "--condition", "demo", "--no-learn"] if arm == "expert" else ["--pilot", "precland"]
    _run([col(), "fly", *pilot, "--config", _rel(config_name(arm, level)), "--episodes", str(STARTS),
          "--seed", str(FIRST_START), "--run-dir", _rel(run_dir), "--no-pictures"], RUNS / f"{name}.log")
    _keep(run_dir, name)


def policies(grid_run: Path | None) -> None:
    """The 8 policies' folders: a trial the grid's own run folder (``grid_run``, the pinned
    grid being run) already holds is taken from there; the others are rerun from the committed
    pinned grid with ``--verify --keep`` (their lines must be the committed ones). Then each keeps
    its level-0.2 evaluation (the grid's own) and flies the level-0 starts."""
    kept = RUNS / "policies"
    folders = {key: grid_run / "trials" / key for key in POLICIES
               if grid_run is not None and (grid_run / "trials" / key / "eval_episodes.jsonl").exists()}
    folders.update({key: kept / key / "trials" / key for key in POLICIES
                    if key not in folders and (kept / key / "trials" / key / "eval_episodes.jsonl").exists()})
    committed = {json.loads(line)["trial"]["key"] for line in (GRID / "results.jsonl").read_text().splitlines()}
    rerun = [key for key in POLICIES if key not in folders and key in committed]
    if rerun:
        work = RUNS / f"policies-verify-{len(list(RUNS.glob('policies-verify-*.log')))}"
        cmd = [col(), "experiment", "--verify", _rel(GRID), "--keep", _rel(work)]
        for key in rerun:
            cmd += ["--trial", key]
        log = work.with_suffix(".log")
        log.parent.mkdir(parents=True, exist_ok=True)
        with log.open("w") as out:
            done = subprocess.run(cmd, stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, cwd=ROOT)
        lines = log.read_text().splitlines()
        verdict = json.loads(lines[-1])
        verdict["per_trial"] = [ln for ln in lines if ln.split(":")[0] in rerun]
        verdict["exit_code"] = done.returncode
        with (HERE / "policies.jsonl").open("a") as f:
            f.write(json.dumps(verdict) + "\n")
        for key in rerun:
            (kept / key).parent.mkdir(parents=True, exist_ok=True)
            shutil.move(str(work / key), str(kept / key))
            folders[key] = kept / key / "trials" / key
    missing = [key for key in POLICIES if key not in folders]
    if missing:
        print(f"not yet finished by the pinned grid (run this step again later): {', '.join(missing)}")
    EPISODES.mkdir(parents=True, exist_ok=True)
    for key in sorted(folders):
        trial = folders[key]
        if not (EPISODES / f"{key}-level-0.2.jsonl").exists():
            shutil.copy(trial / "eval_episodes.jsonl", EPISODES / f"{key}-level-0.2.jsonl")
        name = f"{key}-level-0"
        if (EPISODES / f"{name}.jsonl").exists():
            continue
        checkpoint = trial / "train" / "checkpoints" / "episode_019.npz"  # the run's key is the trial's at 20
        run_dir = RUNS / name
        shutil.rmtree(run_dir, ignore_errors=True)
        _run([col(), "eval", _rel(checkpoint), "--config", _rel(config_name("expert", "0")), "--episodes", str(STARTS),
              "--seed", str(FIRST_START), "--run-dir", _rel(run_dir), "--no-pictures"], RUNS / f"{name}.log")
        _keep(run_dir, name)


def real(arm: str) -> None:
    from companion.testing.autopilots import find_autopilots, start_px4

    name = f"real-px4-{arm}"
    if (EPISODES / f"{name}.jsonl").exists():
        return
    root, why = find_autopilots()
    if root is None:
        raise SystemExit(why)
    work = Path(tempfile.mkdtemp(prefix="precland-real-"))
    ap = start_px4(root, work / "px4")
    run_dir = RUNS / name
    shutil.rmtree(run_dir, ignore_errors=True)
    pilot = ["--pilot", "expert", "--condition", "demo", "--no-learn"] if arm == "expert" else ["--pilot", "precland"]
    try:
        config = CONFIGS / ("real-px4-colour-pad.toml" if arm == "expert" else "real-px4.toml")
        _run([col(), "fly", *pilot, "--connect", ap.connection, "--config", _rel(config),
              "--episodes", str(REAL_STARTS), "--seed", str(FIRST_START), "--run-dir", _rel(run_dir), "--no-pictures"],
             RUNS / f"{name}.log")
    finally:
        ap.stop()
    _keep(run_dir, name)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="step", required=True)
    sub.add_parser("configs")
    one = sub.add_parser("fly")
    one.add_argument("arm", choices=ARMS)
    one.add_argument("level", choices=LEVELS)
    pol = sub.add_parser("policies")
    pol.add_argument("--grid-run", type=Path, help="the pinned grid's run folder: trials found there are not rerun")
    r = sub.add_parser("real")
    r.add_argument("arm", choices=("precland", "expert"))
    sub.add_parser("summarise")
    sub.add_parser("records")
    args = parser.parse_args()
    if args.step == "configs":
        write_configs()
    elif args.step == "fly":
        fly(args.arm, args.level)
    elif args.step == "policies":
        policies(args.grid_run)
    elif args.step == "real":
        real(args.arm)
    elif args.step == "records":
        environment_records()
    else:
        from summarise import main as summarise  # type: ignore[import-not-found]

        summarise()


if __name__ == "__main__":
    main()
