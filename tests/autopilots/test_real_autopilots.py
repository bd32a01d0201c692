"""The companion against the real autopilots (PX4 SIH and ArduCopter SITL, built from upstream).

Both are started at once, each on ports of its own, in a fresh working folder, and the same
scenario runs against each in its own thread: the conformance script (compared with our SITL as
the same autopilot), ``col fly --pilot expert`` for three episodes with the camera rendered from
the vehicle's telemetry (``--camera render``), a ``col eval`` of the checkpoint it wrote,
interrupted with Ctrl-C in flight, and a listener on the companion's port after each run that
watches what the vehicle does next. The companion disturbs each autopilot's own simulator a
little (:data:`SIM_EXTRA`): ArduCopter flies in wind, PX4 SIH heavier.

Faster than real time (:data:`SPEEDUP`: PX4 SIH 4x, ArduCopter 5x, our SITL as each at the same
speed; bench/README.md, "The real autopilots faster than real time", says why these): the
companion flies by the vehicle's clock (``[companion.session] clock = "vehicle"``), and every
wait on the vehicle here and in the conformance script counts the vehicle's seconds
(companion/testing/vehicle_time.py), so the tests mean what they meant at real time; the wall
clock only caps them (``wall_cap_s``). ``COL_AUTOPILOT_REPORT_OUT=FILE`` writes each phase's wall
seconds, the speed-up the vehicles kept while the companion flew (read from its tlogs) and the
conformance outcomes, for bench/README.md (nothing here asserts on the wall clock).

Without the autopilots the tests skip and say how to get them; ``COL_REQUIRE_AUTOPILOTS=1``
(set by .ci/run) makes that a failure instead.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import pytest
from pymavlink import mavutil

from companion.simulator import start_sitl
from companion.testing.autopilots import (
    RunningAutopilot,
    free_udp_port,
    start_ardupilot,
    start_px4,
)
from companion.testing.conformance import Outcome, differences, fly_script
from companion.testing.vehicle_time import TlogClock, VehicleClock, wall_cap_s
from tests.autopilots import (  # times real time, each autopilot and our SITL as it
    SPEEDUP,
    autopilots_root,
)
from tests.conftest import ONE_AFTER_ANOTHER

# one xdist worker runs this group in turn: real PX4 SIH lost the companion ("Connection to
# mission computer lost") beside the CPU-bound trial reruns
pytestmark = [pytest.mark.realtime, pytest.mark.autopilot, pytest.mark.timeout(900), pytest.mark.xdist_group(ONE_AFTER_ANOTHER)]
COL = str(Path(sys.executable).with_name("col"))
KINDS = ("px4", "ardupilot")
SHORT = """
[companion.session]
clock = "vehicle"
start_height_above_pad_m = 2.5
start_xy_range_m = 0.5
max_steps = 500
pad_ned_m = [0.0, 0.0, 0.0]
autopilot_sim_disturbance = true
{session_extra}
[companion.perception]
camera = "render"

[sitl.world]
vehicle_height_m = 0.0

[sitl.disturbance]
level = 0.05
"""
SIM_EXTRA = {"px4": "sih_mass_scale = 1.1\n", "ardupilot": ""}
"""Each autopilot's SITL lightly disturbed (companion/link/sim_params.py): ArduCopter in a 0.5 m/s
wind (level 0.05 of 10 m/s) with turbulence; PX4 SIH, which has no wind, 10 % heavier."""
SIM_NOTES = {"px4": ("sim: SIH_MASS=1.1", "PX4 SIH has no wind"),
             "ardupilot": ("sim: SIM_WIND_T=1, SIM_WIND_SPD=0.5, SIM_WIND_DIR=",)}
EXPERT_EPISODES = 3
LANDING_MODES = {"px4": {"LAND"}, "ardupilot": {"LAND"}}  # pymavlink's names of AUTO.LAND and LAND
IN_FLIGHT_S = 3.0  # of the vehicle's time after the take-off: on the way to the start point
T = TypeVar("T")

# How long, of the vehicle's time, a run's end is watched for the disarm. The companion ends a run
# in LAND; the autopilot lands and disarms in its own time. PX4 SIH once took 96 s: the expert's
# last episode timed out 6.7 m up by its estimate, and the landing was detected 96 s later, with
# the estimate still reading 2.4 m up and not moving (bench/results/ci-fresh-2026-12-06-15-failed.txt,
# where 40 s were watched; the next run's own telemetry log showed the rest). Watching ends at the
# disarm, so a longer window costs only when the landing is slow.
LANDING_WATCH_S = 180.0


@dataclass
class Watched:
    """What a listener saw of the vehicle after a companion run ended."""

    modes: list[str] = field(default_factory=list)
    landed_states: list[int] = field(default_factory=list)
    disarmed_after_s: float | None = None  # of the vehicle's time
    heard: bool = False


@dataclass
class Scenario:
    """One autopilot's results, filled in by its thread."""

    kind: str
    expert: subprocess.CompletedProcess[str] | None = None
    expert_records: list[dict[str, Any]] = field(default_factory=list)
    after_expert: Watched | None = None
    interrupted: subprocess.CompletedProcess[str] | None = None
    eval_records: list[dict[str, Any]] = field(default_factory=list)
    after_interrupt: Watched | None = None
    error: str | None = None
    log_tail: str = ""
    conformance: Outcome | None = None  # the scripted flight, before the companion flies
    ours: Outcome | None = None  # the same script against our SITL's personality
    timing: dict[str, Any] = field(default_factory=dict)  # wall seconds per phase, speed kept (not asserted)


def _records(run_dir: Path) -> list[dict[str, Any]]:
    path = run_dir / "episodes.jsonl"
    return [json.loads(line) for line in path.read_text().splitlines()] if path.exists() else []


def watch_vehicle(connection: str, vehicle_s: float) -> Watched:
    """Listen where the companion listened, until the vehicle is seen disarmed or ``vehicle_s``
    of its own time have passed (the wall clock only as a safety cap)."""
    seen, clock = Watched(), VehicleClock()
    link = mavutil.mavlink_connection(connection, source_system=250)
    deadline = time.monotonic() + wall_cap_s(vehicle_s)
    try:
        while time.monotonic() < deadline and clock.seconds < vehicle_s:
            msg = link.recv_match(blocking=True, timeout=0.2)
            if msg is None or msg.get_srcComponent() != 1:
                continue
            clock.observe(msg)
            if msg.get_type() == "EXTENDED_SYS_STATE":
                seen.heard = True
                seen.landed_states.append(int(msg.landed_state))
            elif msg.get_type() == "HEARTBEAT" and _saw_disarmed(seen, msg):
                seen.disarmed_after_s = clock.seconds
                break
    finally:
        link.close()
    return seen


def _saw_disarmed(seen: Watched, msg: Any) -> bool:
    """Fold a HEARTBEAT into ``seen``; True when it is the vehicle's own and says disarmed."""
    seen.heard = True
    if msg.type in (mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_TYPE_ONBOARD_CONTROLLER):
        return False
    mode = mavutil.mode_string_v10(msg)
    if not seen.modes or seen.modes[-1] != mode:
        seen.modes.append(mode)
    return not msg.base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED


def _fly_expert(ap: RunningAutopilot, config: Path, run_dir: Path) -> subprocess.CompletedProcess[str]:
    cmd = [COL, "fly", "--connect", ap.connection, "--config", str(config),
           "--pilot", "expert", "--episodes", str(EXPERT_EPISODES), "--run-dir", str(run_dir)]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=600, stdin=subprocess.DEVNULL)


def _eval_interrupted(ap: RunningAutopilot, config: Path, checkpoint: Path,
                      run_dir: Path) -> subprocess.CompletedProcess[str]:
    """``col eval`` of ``checkpoint``, sent SIGINT :data:`IN_FLIGHT_S` of the vehicle's time after
    its take-off (read from the run's own tlog as it is written)."""
    cmd = [COL, "eval", str(checkpoint), "--connect", ap.connection,
           "--config", str(config), "--episodes", "1", "--run-dir", str(run_dir), "-v"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, stdin=subprocess.DEVNULL)
    lines: list[str] = []
    took_off = threading.Event()

    def read() -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            lines.append(line)
            if "home:" in line:  # logged when the take-off is over, before the flight to the start point
                took_off.set()

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    deadline = time.monotonic() + 240  # a safety cap: arming waits are the companion's, on the wall clock
    while time.monotonic() < deadline and proc.poll() is None and not took_off.wait(0.05):
        pass
    _wait_vehicle_time(TlogClock(run_dir / "session.tlog"), IN_FLIGHT_S, proc)  # a weak policy may land soon after
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
    proc.wait(120)
    reader.join(5)
    return subprocess.CompletedProcess(cmd, proc.returncode, "".join(lines), "")


def _wait_vehicle_time(tlog: TlogClock, seconds: float, proc: subprocess.Popen[str]) -> None:
    """Until ``seconds`` more of the vehicle's time are in the companion's tlog (or it exits)."""
    start = tlog.seconds()
    deadline = time.monotonic() + wall_cap_s(seconds)
    while proc.poll() is None and tlog.seconds() - start < seconds and time.monotonic() < deadline:
        time.sleep(0.02)


def _timed(timing: dict[str, Any], phase: str, run: Callable[[], T]) -> T:
    """``run()``, its wall seconds noted in ``timing`` (for bench/README.md, never asserted)."""
    start = time.monotonic()
    try:
        return run()
    finally:
        timing[f"{phase}_wall_s"] = round(time.monotonic() - start, 1)


def _kept(scenario: Scenario, work: Path) -> None:
    """The speed-up each companion run's vehicle kept, from its tlog; the expert's frame ages."""
    for phase in ("expert", "eval"):
        scenario.timing[f"{phase}_vehicle_speed"] = TlogClock(work / phase / "session.tlog").speed()
    if scenario.expert is not None and scenario.expert.returncode == 0:
        summary = json.loads(scenario.expert.stdout.strip().splitlines()[-1])
        scenario.timing["expert_frame_age_ms"] = summary.get("frame_age_ms")


def run_scenario(scenario: Scenario, ap: RunningAutopilot, config: Path, work: Path) -> None:
    timing = scenario.timing
    try:
        scenario.conformance = _timed(timing, "conformance", lambda: fly_script(ap.connection, slow_s=20.0, fast_s=20.0))
        expert_dir = work / "expert"
        scenario.expert = _timed(timing, "expert", lambda: _fly_expert(ap, config, expert_dir))
        scenario.expert_records = _records(expert_dir)
        scenario.after_expert = _timed(timing, "after_expert", lambda: watch_vehicle(ap.connection, LANDING_WATCH_S))
        checkpoints = sorted((expert_dir / "checkpoints").glob("episode_*.npz"))
        if not checkpoints:
            scenario.error = "the expert run wrote no checkpoint"
            return
        eval_dir = work / "eval"
        scenario.interrupted = _timed(timing, "eval", lambda: _eval_interrupted(ap, config, checkpoints[-1], eval_dir))
        scenario.eval_records = _records(eval_dir)
        scenario.after_interrupt = _timed(timing, "after_interrupt", lambda: watch_vehicle(ap.connection, LANDING_WATCH_S))
        _kept(scenario, work)
    except Exception as exc:  # reported by the tests, with the autopilot's log
        scenario.error = repr(exc)
    finally:
        scenario.log_tail = ap.log_tail()


def _write_report(results: dict[str, Scenario], started_s: float) -> None:
    """``COL_AUTOPILOT_REPORT_OUT``: timings and conformance outcomes as JSON (bench/README.md)."""
    out = os.environ.get("COL_AUTOPILOT_REPORT_OUT")
    if not out:
        return
    report = {"speedup": SPEEDUP, "flights_wall_s": round(time.monotonic() - started_s, 1),
              "load_1min_after": round(os.getloadavg()[0], 2),
              "timing": {k: s.timing for k, s in results.items()},
              "conformance": {k: {"real": s.conformance.to_dict() if s.conformance else None,
                                  "ours": s.ours.to_dict() if s.ours else None} for k, s in results.items()}}
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    Path(out).write_text(json.dumps(report, indent=1) + "\n")


@pytest.fixture(scope="module")
def scenarios(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, Scenario]]:
    root = autopilots_root()
    work = tmp_path_factory.mktemp("autopilots")
    configs = {kind: work / f"short-{kind}.toml" for kind in KINDS}
    for kind, path in configs.items():
        path.write_text(SHORT.format(session_extra=SIM_EXTRA[kind]))
    started_s = time.monotonic()
    started = {"px4": start_px4(root, work / "px4", speedup=SPEEDUP["px4"]),
               "ardupilot": start_ardupilot(root, work / "ardupilot", speedup=SPEEDUP["ardupilot"])}
    ours_config = work / "ours.toml"
    ours_config.write_text("[sitl.personality]\nprearm_settle_s = 4.0\n")
    ours = {}
    for kind in KINDS:  # our SITL as each, for the conformance script (started here: it lives as long as this thread)
        port = free_udp_port()
        ours[kind] = (start_sitl(port, clock="realtime", config=ours_config, camera=False, timeout_s=120.0,
                                 extra_args=["--autopilot", kind, "--speed", f"{SPEEDUP[kind]:g}"]),
                      f"udpin:127.0.0.1:{port}")
    results = {kind: Scenario(kind) for kind in KINDS}

    def fly_ours(kind: str) -> None:
        timing = results[kind].timing
        try:
            results[kind].ours = _timed(timing, "ours_conformance", lambda: fly_script(ours[kind][1], slow_s=20.0, fast_s=20.0))
        finally:  # at N times real time an idle SITL still costs a tenth of a core: not beside the companion's flights
            ours[kind][0].stop()

    try:
        threads = [threading.Thread(target=run_scenario, args=(results[k], started[k], configs[k], work / f"run-{k}"))
                   for k in KINDS] + [threading.Thread(target=fly_ours, args=(k,)) for k in KINDS]
        for t in threads:
            t.start()
        for t in threads:
            t.join(800)
        _write_report(results, started_s)
        yield results
    finally:
        for ap in started.values():
            ap.stop()
        for sitl, _ in ours.values():
            sitl.stop()


def _why(s: Scenario) -> str:
    out = s.expert.stdout[-3000:] + s.expert.stderr[-3000:] if s.expert else ""
    return f"{s.kind}: error={s.error}\n--- companion ---\n{out}\n--- autopilot ---\n{s.log_tail}"


@pytest.mark.parametrize("kind", KINDS)
def test_expert_episodes_end_in_touchdown(scenarios: dict[str, Scenario], kind: str) -> None:
    s = scenarios[kind]
    assert s.expert is not None and s.expert.returncode == 0, _why(s)
    outcomes = [r["outcome"] for r in s.expert_records]
    # The expert on PX4 SIH ends an episode without a touchdown now and then: over its committed
    # runs (results/real-autopilots/render, render-truth-px4*), 200 touchdowns, 6 timeouts, 2 fence
    # stops and 1 error; in CI once a fence stop (bench/results/ci-fresh-2026-12-06-11-failed.txt:
    # the pad lost early, then a search that climbed to 20 m and went 28 m off by the estimate).
    # At least 2 of 3 touchdowns, and the companion never ends one in an error.
    assert len(outcomes) == EXPERT_EPISODES and outcomes.count("touchdown") >= 2, (outcomes, _why(s))
    assert set(outcomes) <= {"touchdown", "timeout", "fence"}, (outcomes, _why(s))
    # judged from the reported position: the rendered pad is where the estimate puts it
    landed = [r for r in s.expert_records if r["outcome"] == "touchdown"]
    assert all(r["success"] is not None for r in s.expert_records)
    assert min(r["touchdown_distance_m"] for r in landed) < 1.5, s.expert_records  # it steered to the pad
    summary = json.loads(s.expert.stdout.strip().splitlines()[-1])
    # Frames rendered from fresh telemetry. Ages are in the vehicle's time, which runs SPEEDUP times
    # the machine's: the tail is bounded by half a second of the machine's time (at a load of 10.7
    # a p95 of 620 vehicle ms at 4x was seen, bench/results/ci-fresh-2026-12-07-25-failed.txt), the
    # median by half a second of the vehicle's (100 ms there); a frame drawn from frozen telemetry
    # ages without bound and fails both.
    assert summary["frame_age_ms"]["p50"] < 500, summary
    assert summary["frame_age_ms"]["p95"] < 500 * SPEEDUP[kind], summary


@pytest.mark.parametrize("kind", KINDS)
def test_each_episode_sets_its_autopilots_own_simulator_as_asked(scenarios: dict[str, Scenario], kind: str) -> None:
    s = scenarios[kind]
    assert s.expert is not None and s.expert.returncode == 0, _why(s)
    for record in s.expert_records:  # every value confirmed by the vehicle's echo, else the episode is an error
        notes = " | ".join(record["notes"])
        assert all(n in notes for n in SIM_NOTES[kind]), notes
    if kind == "ardupilot":  # the direction is drawn per episode, as our SITL draws it
        directions = {n.split("SIM_WIND_DIR=")[1].split(",")[0] for r in s.expert_records for n in r["notes"] if "SIM_WIND_DIR=" in n}
        assert len(directions) == EXPERT_EPISODES, directions


@pytest.mark.parametrize("kind", KINDS)
def test_normal_end_of_run_leaves_the_vehicle_disarmed(scenarios: dict[str, Scenario], kind: str) -> None:
    s = scenarios[kind]
    seen = s.after_expert
    assert seen is not None and seen.heard, _why(s)
    assert seen.disarmed_after_s is not None, (seen, _why(s))


@pytest.mark.parametrize("kind", KINDS)
def test_eval_of_a_checkpoint_flies_and_ctrl_c_lands_then_disarms(scenarios: dict[str, Scenario], kind: str) -> None:
    s = scenarios[kind]
    assert s.interrupted is not None, _why(s)
    out = s.interrupted.stdout
    assert s.interrupted.returncode != 0, out[-3000:]  # interrupted, not finished
    assert "end of run: vehicle" in out, out[-3000:]  # the companion left it landing before it went
    seen = s.after_interrupt
    assert seen is not None and seen.heard, _why(s)
    landing = LANDING_MODES[kind]
    assert any(m in landing for m in seen.modes), (seen, out[-2000:])
    assert seen.disarmed_after_s is not None, (seen, out[-2000:])


@pytest.mark.parametrize("kind", KINDS)
def test_our_sitl_answers_the_scripted_flight_as_the_real_autopilot_does(scenarios: dict[str, Scenario],
                                                                         kind: str) -> None:
    """Arm, take off, offboard, a slow descent (0.26 m/s) then 0.33 m/s, disarm: the same ACKs, the
    same mode, the same landed / not landed at each descent, the same disarm (docs/link.md)."""
    s = scenarios[kind]
    real, ours = s.conformance, s.ours
    assert real is not None and ours is not None, _why(s)
    assert not real.errors and not ours.errors, (real, ours)
    assert differences(real, ours) == [], (real.to_dict(), ours.to_dict())
    for flight in (real, ours):  # each flight judged its own setpoint stream against the vehicle's limit
        assert flight.loss_timeout_s is not None and flight.max_setpoint_gap_s is not None, flight
        assert not flight.stream_broke(), flight
    assert real.loss_timeout_s == pytest.approx(ours.loss_timeout_s), (real.loss_timeout_s, ours.loss_timeout_s)
    if kind == "px4":  # the rule the touchdown assist exists for
        assert real.landed_at_slow_descent_s is None and real.landed_at_fast_descent_s is not None, real


def test_instances_handed_out_at_once_never_share_ports() -> None:
    """Two autopilots started at once found the same ports free before either bound them."""
    from companion.testing import autopilots

    first = autopilots.free_ardupilot_instance()
    second = autopilots.free_ardupilot_instance()
    px4_a, px4_b = autopilots.free_px4_instance(), autopilots.free_px4_instance()
    try:
        assert first != second and px4_a != px4_b
    finally:
        for kind, inst in (("ardupilot", first), ("ardupilot", second), ("px4", px4_a), ("px4", px4_b)):
            autopilots._release(kind, inst)
    assert autopilots.free_ardupilot_instance() == first  # released: handed out again
    autopilots._release("ardupilot", first)


def test_an_instance_claimed_by_another_process_is_not_handed_out() -> None:
    """Two test workers each starting PX4 instance 0 fought over its lock file and one port."""
    from companion.testing import autopilots

    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys; from companion.testing import autopilots as a;"
         "print(a.free_px4_instance(), flush=True); sys.stdin.readline()"],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout is not None and holder.stdin is not None
        theirs = int(holder.stdout.readline())
        ours = autopilots.free_px4_instance()
        autopilots._release("px4", ours)
        assert ours != theirs
    finally:
        holder.kill()
        holder.wait(10)
    assert autopilots.free_px4_instance() == theirs  # its holder died: the kernel dropped the lock
    autopilots._release("px4", theirs)
