"""CI reruns a committed trial of the paper grid and compares its line byte for byte, and
every committed results folder says what numeric environment made it."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from colcommon import numeric_env as ne

ROOT = Path(__file__).resolve().parents[2]
GRID = ROOT / "results" / "paper-grid"


def cheapest_trial(results_dir: Path) -> str:
    """The committed trial whose rerun costs least: a CoL@4 trial (its run trains 4 episodes)
    with the shortest recorded wall time."""
    ok = {json.loads(line)["trial"]["key"] for line in (results_dir / "results.jsonl").read_text().splitlines()
          if json.loads(line)["status"] == "ok"}
    times = [json.loads(line) for line in (results_dir / "timings.jsonl").read_text().splitlines()]
    costs = {t["trial"]: t["train_wall_s"] + t["eval_wall_s"] for t in times
             if t["trial"] in ok and "-col-04-" in t["trial"] and t["eval_wall_s"] > 0}
    return min(costs, key=costs.__getitem__)


def test_every_committed_results_folder_records_its_environment() -> None:
    folders = [p for p in (ROOT / "results").iterdir() if p.is_dir()]
    folders += [p for p in (ROOT / "results" / "calibration").iterdir() if p.is_dir()]
    folders += [p for p in (GRID / "variants").iterdir() if p.is_dir()] if (GRID / "variants").is_dir() else []
    missing = [str(p.relative_to(ROOT)) for p in folders
               if p.name != "calibration" and not ne.read_records(p)]
    assert not missing, f"no environment.jsonl in {missing}"


@pytest.mark.skipif(ne.why_not_pinned({}, os.uname().machine, ne.cpu_flags()) is not None,
                    reason="this CPU cannot run the x86-64-v3 profile the grid was made with")
def test_a_committed_trial_reruns_byte_for_byte() -> None:
    (record, *_) = ne.read_records(GRID)
    assert record["profile"] == ne.PROFILE, "the committed grid was not made under the pinned profile"
    key = cheapest_trial(GRID)
    env = {k: v for k, v in os.environ.items() if k not in ne.PINNED}
    env["OPENBLAS_CORETYPE"] = "SkylakeX"  # what an unpinned AVX-512 machine would pick: overridden
    col = Path(sys.executable).with_name("col")
    out = subprocess.run([str(col), "experiment", "--verify", str(GRID), "--trial", key], env=env, cwd=ROOT,
                         capture_output=True, text=True, timeout=1200)
    summary = json.loads(out.stdout.strip().splitlines()[-1])
    assert out.returncode == 0 and summary["identical"] == 1, out.stdout + out.stderr[-2000:]
    assert summary["environment_differences"] == []
