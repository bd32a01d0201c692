"""``col fly --pilot precland`` end to end: our SITL renders the ArUco board, the companion flies to
the episode start, asks for the precision landing (PX4 personality, lockstep: AUTO.PRECLAND;
ArduPilot personality, real time: PLND_* and LAND) and streams LANDING_TARGET from its detector;
the autopilot's precision landing lands on the pad."""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import pytest
from pymavlink import mavutil

from tests.test_fly_e2e import col_command, read_records, tlog_types

pytestmark = pytest.mark.e2e
CONFIG = Path(__file__).resolve().parents[1] / "configs" / "precland.toml"


def fly_precland(run_dir: Path, config: Path, episodes: int) -> tuple[dict, list[dict]]:
    """``col fly --pilot precland`` on the held-out starts; its summary and episode records."""
    args = [*col_command(), "fly", "--pilot", "precland", "--config", str(config), "--episodes", str(episodes),
            "--seed", "100000", "--run-dir", str(run_dir), "--no-pictures"]
    done = subprocess.run(args, capture_output=True, text=True, timeout=280, env=dict(os.environ, OMP_NUM_THREADS="1"))
    assert done.returncode == 0, f"col fly failed ({done.returncode}):\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}"
    return json.loads(done.stdout.strip().splitlines()[-1]), read_records(run_dir)


def sent(tlog: Path, kind: str) -> list:  # type: ignore[type-arg]
    """The companion's messages of one type in a run's tlog (it logs both directions)."""
    log = mavutil.mavlink_connection(str(tlog), dialect="ardupilotmega")
    found = []
    try:
        while (msg := log.recv_match(type=kind)) is not None:
            found.append(msg)
    finally:
        log.close()
    return found


def test_precland_lands_on_the_pad_from_the_held_out_starts(tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    summary, records = fly_precland(run_dir, CONFIG, 2)
    report = "; ".join(f"ep{r['episode']} {r['outcome']} d={r['touchdown_distance_m']} t={r['sim_time_s']} {r['notes']}"
                       for r in records)
    assert [r["outcome"] for r in records] == ["touchdown", "touchdown"], report
    assert all(r["phase"] == "autonomous" and r["human_samples"] == 0 for r in records), report
    assert summary["successes"] == 2, report  # within the paper's 0.5 m of the pad's centre
    assert all(r["touchdown_distance_m"] < 0.3 for r in records), report
    assert all(any("LANDING_TARGET" in n and not n.startswith("precland: 0 ") for n in r["notes"]) for r in records), report
    assert tlog_types(run_dir / "session.tlog").get("LANDING_TARGET", 0) > 20


@pytest.mark.realtime
def test_precland_on_the_ardupilot_personality(tmp_path: Path) -> None:
    """ArduCopter's way: PLND_ENABLED and PLND_TYPE set, LAND, targets in BODY_FRD (real time)."""
    config = tmp_path / "ardupilot.toml"
    config.write_text('[sitl.camera]\npad_marker = "aruco"\n\n[sitl.personality]\nautopilot = "ardupilot"\n'
                      "prearm_settle_s = 2.0\n")
    run_dir = tmp_path / "run"
    summary, records = fly_precland(run_dir, config, 1)
    assert [r["outcome"] for r in records] == ["touchdown"], records
    assert summary["successes"] == 1 and records[0]["touchdown_distance_m"] < 0.3, records
    params = {m.param_id: m.param_value for m in sent(run_dir / "session.tlog", "PARAM_SET")}
    assert params.get("PLND_ENABLED") == 1.0 and params.get("PLND_TYPE") == 1.0, params
    targets = sent(run_dir / "session.tlog", "LANDING_TARGET")
    assert len(targets) > 20 and {m.frame for m in targets} == {12}
    rate_hz = (len(targets) - 1) / ((targets[-1].time_usec - targets[0].time_usec) / 1e6)
    assert 7.0 < rate_hz < 12.0, rate_hz  # the SITL camera's 10.5 frames per second
