"""A rendered pad that drives, on real ArduCopter SITL: the touchdown by the SITL's truth.

Real ArduCopter following a driving rendered pad down touches its own still ground and its land
detector never fires (results/moving-pad/sweep/RUN.md). With ``[companion.session]
touchdown_by_truth_contact`` (companion/control/truth_contact.py) the first ground contact by its
truth (SIM_STATE) ends the episode as a touchdown, scored against the pad where it then is, and
the forced disarm lets the next episode take off. Here: the leading expert, two episodes on a pad
driving at 1 m/s, from 2.5 m, at the speed-up the other real-autopilot tests use.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from companion.control.touchdown import TRUTH_CONTACT_NOTE
from companion.testing.autopilots import start_ardupilot
from tests.autopilots import SPEEDUP, autopilots_root
from tests.conftest import ONE_AFTER_ANOTHER

pytestmark = [pytest.mark.realtime, pytest.mark.autopilot, pytest.mark.timeout(600), pytest.mark.xdist_group(ONE_AFTER_ANOTHER)]
COL = str(Path(sys.executable).with_name("col"))
CONFIG = """
[companion.pilot]
lead_moving_pad = true

[companion.session]
clock = "vehicle"
start_height_above_pad_m = 2.5
start_xy_range_m = 0.5
pad_ned_m = [0.0, 0.0, 0.0]
touchdown_by_truth_contact = true

[companion.perception]
camera = "render"

[sitl.world]
vehicle_height_m = 0.0
vehicle_velocity_ne_m_s = [0.8, 0.6]
"""


@pytest.fixture(scope="module")
def records(tmp_path_factory: pytest.TempPathFactory) -> tuple[list[dict], str]:
    root = autopilots_root()
    work = tmp_path_factory.mktemp("moving-pad-real")
    config = work / "moving.toml"
    config.write_text(CONFIG)
    with start_ardupilot(root, work / "ardupilot", speedup=SPEEDUP["ardupilot"]) as ap:
        done = subprocess.run([COL, "fly", "--connect", ap.connection, "--config", str(config), "--pilot", "expert",
                               "--episodes", "2", "--run-dir", str(work / "run"), "--no-pictures"],
                              capture_output=True, text=True, timeout=480, stdin=subprocess.DEVNULL)
        log = f"exit {done.returncode}\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}\n--- ArduCopter ---\n{ap.log_tail()}"
    path = work / "run" / "episodes.jsonl"
    return ([json.loads(line) for line in path.read_text().splitlines()] if path.exists() else []), log


def test_each_episode_ends_at_the_truths_ground_contact_scored_where_the_pad_then_is(records: tuple[list[dict], str]) -> None:
    episodes, log = records
    assert [r["outcome"] for r in episodes] == ["touchdown", "touchdown"], log
    for r in episodes:
        assert TRUTH_CONTACT_NOTE in r["notes"], r["notes"]
        assert "disarmed (forced) after the truth's touchdown" in r["notes"], r["notes"]
        assert r["true_touchdown_distance_m"] is not None and r["success"] is not None, r
    # the second episode took off from the ground the forced disarm left it on, and flew
    assert "started by flying to the start point" in episodes[1]["notes"], episodes[1]["notes"]
