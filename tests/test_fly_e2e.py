"""``col fly`` end to end: the real CLI starts the real SITL in lockstep and the scripted expert
lands on the pad; the run folder holds what docs say it holds (dataset, checkpoints, records, tlog).

The 20-episode run is the issue's acceptance test (>= 90 % landings). It takes 16-25 s on the
shared 2-core machine, too much of the default suite's budget with the other end-to-end tests,
so it is marked slow; a 3-episode run (about 10 s) checks the same path by default.
"""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
from pymavlink import mavutil

pytestmark = pytest.mark.e2e


def col_command() -> list[str]:
    """The installed ``col`` console script beside this interpreter, else the module."""
    script = Path(sys.executable).with_name("col")
    return [str(script)] if script.exists() else [sys.executable, "-m", "companion.cli"]


def fly_expert(run_dir: Path, episodes: int, timeout_s: float) -> tuple[dict[str, Any], float]:
    """Run ``col fly`` with the expert demonstrating; its summary JSON and the wall time taken."""
    args = [*col_command(), "fly", "--pilot", "expert", "--episodes", str(episodes), "--condition", "demo",
            "--no-learn", "--seed", "0", "--run-dir", str(run_dir)]
    env = dict(os.environ, OMP_NUM_THREADS="1")
    t0 = time.monotonic()
    done = subprocess.run(args, capture_output=True, text=True, timeout=timeout_s, env=env)
    wall_s = time.monotonic() - t0
    assert done.returncode == 0, f"col fly failed ({done.returncode}):\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}"
    last = done.stdout.strip().splitlines()[-1]
    return json.loads(last), wall_s


def read_records(run_dir: Path) -> list[dict[str, Any]]:
    lines = (run_dir / "episodes.jsonl").read_text().splitlines()
    return [json.loads(line) for line in lines if line.strip()]


def read_dataset(run_dir: Path) -> list[dict[str, str]]:
    with (run_dir / "human.csv").open(newline="") as f:
        return list(csv.DictReader(f))


def tlog_types(path: Path) -> dict[str, int]:
    """Message counts of a tlog as pymavlink (hence MAVProxy and friends) reads it back."""
    log = mavutil.mavlink_connection(str(path), dialect="common")
    counts: dict[str, int] = {}
    try:
        while (msg := log.recv_match()) is not None:
            counts[msg.get_type()] = counts.get(msg.get_type(), 0) + 1
    finally:
        log.close()
    return counts


def landing_report(records: list[dict[str, Any]]) -> str:
    """Outcome and touchdown distance per episode: what to look at when the expert misses."""
    return "; ".join(f"ep{r['episode']} {r['outcome']} d={r['touchdown_distance_m']} v={r['touchdown_speed_m_s']}"
                     for r in records)


def check_run_folder(run_dir: Path, summary: dict[str, Any], episodes: int) -> list[dict[str, Any]]:
    """The run folder matches the summary: records, dataset rows, checkpoints, a readable tlog."""
    records = read_records(run_dir)
    assert [r["episode"] for r in records] == list(range(episodes))
    assert summary["episodes"] == episodes
    assert summary["successes"] == sum(bool(r["success"]) for r in records)
    rows = read_dataset(run_dir)
    assert len(rows) > 0
    assert len(rows) == summary["human_samples"] == sum(r["human_samples"] for r in records)
    assert {row["source"] for row in rows} == {"demonstration"}  # demo: every step is the expert's
    assert all(r["human_samples"] == r["steps"] for r in records)
    checkpoints = sorted((run_dir / "checkpoints").glob("episode_*.npz"))
    assert [p.name for p in checkpoints] == [f"episode_{i:03d}.npz" for i in range(episodes)]
    counts = tlog_types(run_dir / "session.tlog")
    assert counts.get("HEARTBEAT", 0) > 0 and counts.get("ATTITUDE", 0) > 0
    assert counts.get("SET_POSITION_TARGET_LOCAL_NED", 0) >= summary["human_samples"]  # what we sent
    return records


def test_col_fly_expert_three_episodes_writes_a_complete_run(tmp_path: Path) -> None:
    summary, _ = fly_expert(tmp_path / "run", episodes=3, timeout_s=120)
    records = check_run_folder(tmp_path / "run", summary, episodes=3)
    assert summary["successes"] >= 2, landing_report(records)
    assert all(r["outcome"] == "touchdown" for r in records), landing_report(records)
    check_pictures(tmp_path / "run", records)


def check_pictures(run_dir: Path, records: list[dict[str, Any]]) -> None:
    """flight.png, and the last episode's video: one frame with its HUD per control step."""
    av = pytest.importorskip("av")
    assert (run_dir / "flight.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    videos = sorted(p.name for p in run_dir.glob("episode_*.mp4"))
    assert videos == [f"episode_{records[-1]['episode']:03d}.mp4"]
    with av.open(str(run_dir / videos[0])) as container:
        frames = list(container.decode(video=0))
    assert len(frames) == records[-1]["steps"] and (frames[0].width, frames[0].height) == (640, 480)


@pytest.mark.slow
def test_col_fly_expert_lands_on_the_pad_in_90_percent_of_20_seeded_episodes(tmp_path: Path) -> None:
    summary, wall_s = fly_expert(tmp_path / "run", episodes=20, timeout_s=300)
    records = check_run_folder(tmp_path / "run", summary, episodes=20)
    assert summary["successes"] >= 18, f"{summary['successes']}/20 in {wall_s:.1f} s: {landing_report(records)}"
    distances = [r["touchdown_distance_m"] for r in records if r["touchdown_distance_m"] is not None]
    assert len(distances) == 20 and max(sorted(distances)[:18]) <= 0.5


def test_the_same_seed_records_the_same_dataset_byte_for_byte(tmp_path: Path) -> None:
    """Lockstep runs are a function of their seed: two runs write identical human.csv files."""
    fly_expert(tmp_path / "a", 2, timeout_s=180)
    fly_expert(tmp_path / "b", 2, timeout_s=180)
    a = (tmp_path / "a" / "human.csv").read_bytes()
    assert len(a.splitlines()) > 300
    assert a == (tmp_path / "b" / "human.csv").read_bytes()
