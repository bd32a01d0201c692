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
HARDWARE = ("cpu_model:", "cpu_flags:", "numpy_dispatch:")  # what the CPU has, not what the run asked for


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
    groups = [p for p in folders if not any(c.is_file() for c in p.iterdir())]  # e.g. calibration/, precland/
    folders = [p for p in folders if p not in groups] + [c for g in groups for c in g.iterdir() if c.is_dir()]
    folders += [p for p in (GRID / "variants").iterdir() if p.is_dir()] if (GRID / "variants").is_dir() else []
    missing = [str(p.relative_to(ROOT)) for p in folders if not ne.read_records(p)]
    assert not missing, f"no environment.jsonl in {missing}"


def _recorded_environ() -> dict[str, str] | None:
    records = ne.read_records(GRID)
    return ne.environ_of_record(records[0]) if records else None


@pytest.mark.skipif(not (_recorded_environ() and ne.can_run_environ(_recorded_environ() or {}, os.uname().machine,
                                                                    ne.cpu_flags())),
                    reason="this CPU cannot run the kernels the committed grid was made with")
@pytest.mark.xdist_group("cpu-heavy")  # lockstep: one CPU-heavy unit at a time beside the real-time tests
@pytest.mark.timeout(1500)  # ~146 s on an idle machine, over 300 s at load ~11
def test_a_committed_trial_reruns_byte_for_byte() -> None:
    """``--verify`` reruns the trial in the environment the folder recorded, whatever the shell
    asks for (here OpenBLAS's SSE3 kernels, which neither the grid nor the profile uses)."""
    key = cheapest_trial(GRID)
    env = {k: v for k, v in os.environ.items() if k not in ne.PINNED}
    env["OPENBLAS_CORETYPE"] = "Prescott"
    col = Path(sys.executable).with_name("col")
    out = subprocess.run([str(col), "experiment", "--verify", str(GRID), "--trial", key], env=env, cwd=ROOT,
                         capture_output=True, text=True, timeout=1200)
    summary = json.loads(out.stdout.strip().splitlines()[-1])
    assert out.returncode == 0 and summary["identical"] == 1, out.stdout + out.stderr[-2000:]
    # The software environment is the recorded one; on another CPU its own facts differ (and are
    # reported): the committed grid was made on an Intel Xeon with AMX and reruns on an AMD EPYC.
    software = [d for d in summary["environment_differences"] if not d.startswith(HARDWARE)]
    assert software == [], summary["environment_differences"]
