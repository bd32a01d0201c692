"""Why the policies fail: the diagnosis preregistered in docs/learner.md ("Why the policies fail:
the diagnosis plan", committed in 78488a8 before any of these runs).

The 24 policies: CoL@20 and Demo@20 of P1-P4, replicate 0, from the pinned paper grid
(results/paper-grid), then of H01-H08, replicate 0, from the human-like grid (results/human-like).
Steps, from the repository's root, each resumable (a policy whose output exists is skipped):

    python results/learner-diagnosis/run.py verify [KEY ...]    # retrain: col experiment --verify --keep
    python results/learner-diagnosis/run.py fly [KEY ...]       # endpoints 1-3 on the identical reruns
    python results/learner-diagnosis/run.py fit [KEY ...]       # endpoint 4 (converged, reseeded; each flown)
    python results/learner-diagnosis/run.py summarise           # summary.json and table.md

Without KEYs a step takes every policy, the paper grid's first. The script re-executes itself
under the project's numeric profile (colcommon/numeric_env.py), as `col experiment` does, so
its flights are the experiment's evaluation bit for bit (each flight of a final policy is
checked against the rerun's own eval_episodes.jsonl).

Run folders (the reruns' datasets and checkpoints, per-step arrays) go to runs/learner-diagnosis/,
which is not committed. What is committed here: verify.jsonl (every rerun's verdict),
episodes/<grid>/<policy>.jsonl (one line per held-out start: outcome, distance, phases, the
teacher's action gaps, nearest-neighbour distances), fit/<policy>.json (endpoint 4's training
records) and the summaries.
"""

from __future__ import annotations

import sys

if __name__ == "__main__":  # before numpy loads: the numeric profile the grids were made under
    sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parents[2]))
    from colcommon.numeric_env import ensure_pinned

    _why = ensure_pinned(sys.argv)
    if _why is not None:
        print(f"numeric profile not applied: {_why}", file=sys.stderr)

import argparse
import json
import os
import shutil
import subprocess
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
RUNS = ROOT / "runs" / "learner-diagnosis"
GRIDS = {"paper-grid": ("P1", "P2", "P3", "P4"),
         "human-like": tuple(f"H{i:02d}" for i in range(1, 9))}
CONDITIONS = ("col", "demo")
POLICIES: list[tuple[str, str]] = [(grid, f"{p}-{c}-20-s0") for grid, people in GRIDS.items()
                                   for c in CONDITIONS for p in people]
VERIFY = HERE / "verify.jsonl"


def _rel(path: Path) -> str:
    """A path as the commands (run from the repository's root) name it."""
    return os.path.relpath(path, ROOT)


def grid_of(key: str) -> str:
    for grid, key2 in POLICIES:
        if key2 == key:
            return grid
    raise SystemExit(f"{key} is not one of the diagnosed policies: {', '.join(k for _, k in POLICIES)}")


def chosen(keys: list[str]) -> list[tuple[str, str]]:
    return [(grid_of(k), k) for k in keys] if keys else list(POLICIES)


def commit() -> str:
    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no", "--", "companion", "sitl",
                            "colcommon", "configs"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    return head + ("+dirty" if dirty else "")


# ----- step 1: the reruns -----------------------------------------------------------------------
def verdicts() -> dict[str, dict]:
    """The last verdict of every rerun policy (verify.jsonl)."""
    if not VERIFY.exists():
        return {}
    return {r["key"]: r for r in (json.loads(line) for line in VERIFY.read_text().splitlines() if line.strip())}


def kept(grid: str, key: str) -> Path:
    """The rerun's output folder (``--keep``): trials/<key>/train and trials/<key>/eval_episodes.jsonl."""
    return RUNS / grid / key / key


def verify(keys: list[str]) -> None:
    """``col experiment --verify results/<grid> --trial KEY --keep runs/learner-diagnosis/<grid>/KEY``,
    one policy at a time; its verdict goes to verify.jsonl."""
    done = verdicts()
    for grid, key in chosen(keys):
        if key in done:
            continue
        keep = RUNS / grid / key
        shutil.rmtree(keep, ignore_errors=True)  # an interrupted rerun starts over
        keep.parent.mkdir(parents=True, exist_ok=True)
        log = RUNS / grid / f"{key}.verify.log"
        cmd = [_rel(ROOT / ".venv" / "bin" / "col"), "experiment", "--verify", _rel(ROOT / "results" / grid),
               "--trial", key, "--keep", _rel(keep)]
        print(" ".join(cmd), flush=True)
        with log.open("w") as out:
            code = subprocess.run(cmd, stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, cwd=ROOT).returncode
        lines = log.read_text().splitlines()
        summary = next((json.loads(line) for line in reversed(lines) if line.startswith("{\"verified\"")), None)
        per_trial = [line for line in lines if line.startswith(f"{key}: ")]
        if summary is None or not per_trial:
            raise SystemExit(f"{' '.join(cmd)} gave no verdict (exit {code}); see {_rel(log)}")
        record = {"grid": grid, "key": key, "identical": summary["identical"] == 1 and code == 0,
                  "verdict": per_trial[-1], "environment_differences": summary["environment_differences"],
                  "exit_code": code, "command": " ".join(cmd), "commit": commit()}
        with VERIFY.open("a") as fh:
            fh.write(json.dumps(record) + "\n")
        print(per_trial[-1], flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("step", choices=("verify", "fly", "fit", "summarise"))
    parser.add_argument("keys", nargs="*", help="policies (e.g. P1-col-20-s0); default: all 24")
    args = parser.parse_args()
    os.chdir(ROOT)
    if args.step == "verify":
        verify(args.keys)
    else:
        raise SystemExit(f"step {args.step} is not written yet")


if __name__ == "__main__":
    main()
