"""Why the policies fail: the diagnosis preregistered in docs/learner.md ("Why the policies fail:
the diagnosis plan", committed in 78488a8 before any of these runs).

The 24 policies: CoL@20 and Demo@20 of P1-P4, replicate 0, from the pinned paper grid
(results/paper-grid), then of H01-H08, replicate 0, from the human-like grid (results/human-like).
Steps, from the repository's root, each resumable (a policy whose output exists is skipped):

    python results/learner-diagnosis/run.py code                # the code the diagnosis runs: a clean export
    python results/learner-diagnosis/run.py verify [KEY ...]    # retrain: col experiment --verify --keep
    python results/learner-diagnosis/run.py fly [KEY ...]       # endpoints 1-3 on the identical reruns
    python results/learner-diagnosis/run.py fit [KEY ...]       # endpoint 4 (converged, reseeded; each flown)
    python results/learner-diagnosis/run.py summarise           # summary.json and table.md

Without KEYs a step takes every policy, the paper grid's first. Every step after `code` runs
the library of one commit, exported clean (`git archive`) to runs/learner-diagnosis/code/ (its
commit in COMMIT there), whatever the working tree holds meanwhile: the export comes first on
the import path, and the reruns and their SITLs run from inside it. The script re-executes itself
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
    _root = __import__("pathlib").Path(__file__).resolve().parents[2]
    _code = _root / "runs" / "learner-diagnosis" / "code"
    sys.path.insert(0, str(_code if (_code / "COMMIT").exists() and sys.argv[1:2] != ["code"] else _root))
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
CODE = RUNS / "code"
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


def export_code() -> None:
    """runs/learner-diagnosis/code/: the repository at HEAD as committed (``git archive``), so the
    diagnosis runs one commit's library while the working tree changes."""
    if (CODE / "COMMIT").exists():
        print(f"{_rel(CODE)} holds {commit()} already")
        return
    shutil.rmtree(CODE, ignore_errors=True)
    CODE.mkdir(parents=True)
    head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True, check=True).stdout.strip()
    archive = subprocess.run(["git", "archive", head], cwd=ROOT, capture_output=True, check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(CODE)], input=archive, check=True)
    (CODE / "COMMIT").write_text(head + "\n")
    print(f"{_rel(CODE)}: {head}")


def commit() -> str:
    """The commit whose library the steps run (the export's)."""
    return (CODE / "COMMIT").read_text().strip()[:7]


def code_env() -> dict[str, str]:
    """The environment of a subprocess that runs the exported library."""
    return {**os.environ, "PYTHONPATH": str(CODE)}


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
        cmd = ["col", "experiment", "--verify", f"results/{grid}", "--trial", key, "--keep", _rel(keep)]
        print(" ".join(cmd), flush=True)
        with log.open("w") as out:  # from inside the export: its results/<grid> are the committed ones
            code = subprocess.run([str(ROOT / ".venv" / "bin" / "col"), *cmd[1:-1], str(keep)], stdout=out,
                                  stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, cwd=CODE, env=code_env()).returncode
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
    parser.add_argument("step", choices=("code", "verify", "fly", "fit", "summarise"))
    parser.add_argument("keys", nargs="*", help="policies (e.g. P1-col-20-s0); default: all 24")
    args = parser.parse_args()
    if args.step == "code":
        export_code()
        return
    if not (CODE / "COMMIT").exists():
        raise SystemExit(f"run the step 'code' first: {_rel(CODE)} is missing")
    os.chdir(CODE)  # the experiment files and committed grids as the export holds them
    if args.step == "verify":
        verify(args.keys)
    else:
        raise SystemExit(f"step {args.step} is not written yet")


if __name__ == "__main__":
    main()
