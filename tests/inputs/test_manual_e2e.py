"""A person at a ground station intervenes through MANUAL_CONTROL, end to end and in real time.

The SITL runs its real-time clock with a second UDP pair for a ground station. The test's ground
station sends MANUAL_CONTROL addressed to the vehicle (as QGroundControl does); the SITL forwards
it to the companion, which flies ``--pilot manual --condition int``. The ground station holds the
override button for a while in the middle of the episode. Expected: exactly the steps whose
latest MANUAL_CONTROL had the button held are recorded, tagged intervention; their setpoints are
the person's sticks; the vehicle climbs and moves forward as the sticks say.
"""

from __future__ import annotations

import csv
import math
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as M

from companion.app import RunOptions, run_episodes
from companion.commands import CommandMapper
from companion.config import load_companion_config
from companion.msg.command import JoystickCommand
from companion.simulator import SimulatorClient, SitlProcess, start_sitl
from tests.conftest import free_port, gap_steps
from tests.mav_client import MavTestClient

pytestmark = [pytest.mark.realtime, pytest.mark.e2e]

OFFBOARD = 6 << 16
PITCH, THROTTLE = 0.5, 0.5  # the person's sticks while the button is held
BODY_VELOCITY_MASK = 0x5C7
HOLD_AFTER_OFFBOARD_S = 0.8  # the policy flies first ...
HOLD_FOR_S = 2.2  # ... then the person for this long, then the policy again
MAX_STEPS = 45  # about 4.3 s at 10.5 Hz
MANUAL_TIMEOUT_S = 2.0  # well under HOLD_FOR_S's end to the episode's: the release still shows


class GroundStation(threading.Thread):
    """Sends MANUAL_CONTROL at 20 Hz; holds button 0 for ``HOLD_FOR_S`` once OFFBOARD shows."""

    def __init__(self, client: MavTestClient) -> None:
        super().__init__(name="test-ground-station", daemon=True)
        self.client = client
        self.stop = threading.Event()
        self.offboard_s: float | None = None
        self.sent_held = 0

    def sticks(self, now: float) -> tuple[int, int, int, int, int]:
        """x, y, z, r, buttons for this instant (z is QGC's 0..1000 thrust, 500 centred)."""
        t = None if self.offboard_s is None else now - self.offboard_s
        if t is not None and HOLD_AFTER_OFFBOARD_S <= t < HOLD_AFTER_OFFBOARD_S + HOLD_FOR_S:
            return int(PITCH * 1000), 0, int(500 + THROTTLE * 500), 0, 1
        return 0, 0, 500, 0, 0

    def run(self) -> None:
        c = self.client
        while not self.stop.is_set():
            for msg in c.pump(0.05):
                if msg.get_type() == "HEARTBEAT" and msg.get_srcComponent() == 1 and msg.custom_mode == OFFBOARD:
                    self.offboard_s = self.offboard_s or time.monotonic()
            if c.peer is None:
                continue
            x, y, z, r, buttons = self.sticks(time.monotonic())
            c.send(M.MAVLink_manual_control_message(1, x, y, z, r, buttons))
            self.sent_held += buttons


@pytest.fixture
def ground_station() -> Iterator[MavTestClient]:
    c = MavTestClient()
    yield c
    c.close()


@pytest.fixture
def sitl(ground_station: MavTestClient) -> Iterator[tuple[SitlProcess, int]]:
    """A real-time SITL sending to the companion's port and to the ground station's."""
    companion_port = free_port()
    proc = start_sitl(companion_port, clock="realtime", camera=True, seed=3,
                      extra_args=["--udp", f"0:{ground_station.port}"])
    yield proc, companion_port
    proc.stop()


def write_config(path: Path, start_ned: list[float], camera_uri: str) -> Path:
    """Short episodes that begin where the SITL's reset put the vehicle (no flight to a start)."""
    height = 4.0
    pad = [start_ned[0], start_ned[1], start_ned[2] + height]
    path.write_text(
        "[companion.session]\n"
        f"max_steps = {MAX_STEPS}\n"
        f"pad_ned_m = [{pad[0]:.4f}, {pad[1]:.4f}, {pad[2]:.4f}]\n"
        f"start_height_above_pad_m = {height}\n"
        "start_xy_range_m = 0.0\n"
        "start_tolerance_m = 1.0\n"
        "[companion.perception]\n"
        f'camera = "{camera_uri}"\n'
        # The override's release after a silent ground station is tested on an injected clock
        # (tests/inputs/test_inputs.py); here a 0.5 s stall of the loaded machine (CI, load 19)
        # had released and re-held the button: two interventions where the person made one.
        "[companion.pilot]\n"
        f"manual_timeout_s = {MANUAL_TIMEOUT_S}\n"
    )
    return path


def read_tlog(tlog: Path) -> tuple[list[tuple[M.MAVLink_message, bool]], list[tuple[float, float, float]]]:
    """From our tlog: each body-velocity setpoint sent, with whether the latest MANUAL_CONTROL
    held button 0; and the vehicle's (log time, forward speed, down speed) as it reported them."""
    log = mavutil.mavlink_connection(str(tlog), dialect="common")
    held, yaw_rad, setpoints, motion = False, 0.0, [], []
    kinds = ["MANUAL_CONTROL", "SET_POSITION_TARGET_LOCAL_NED", "ATTITUDE", "LOCAL_POSITION_NED"]
    try:
        while (msg := log.recv_match(type=kinds)) is not None:
            kind = msg.get_type()
            if kind == "MANUAL_CONTROL":
                held = bool(msg.buttons & 1)
            elif kind == "SET_POSITION_TARGET_LOCAL_NED" and msg.type_mask == BODY_VELOCITY_MASK:
                setpoints.append((msg, held))
            elif kind == "ATTITUDE":
                yaw_rad = msg.yaw
            elif kind == "LOCAL_POSITION_NED":
                forward = msg.vx * math.cos(yaw_rad) + msg.vy * math.sin(yaw_rad)
                motion.append((msg._timestamp, forward, msg.vz))
    finally:
        log.close()
    return setpoints, motion


@pytest.mark.timeout(90)
def test_ground_station_override_is_flown_and_only_its_steps_are_recorded(
    tmp_path: Path, ground_station: MavTestClient, sitl: tuple[SitlProcess, int]
) -> None:
    proc, companion_port = sitl
    simulator = SimulatorClient("127.0.0.1", proc.control_port)
    try:
        start = simulator.reset(3)["start_ned"]  # hovering, armed, in AUTO.LOITER
    finally:
        simulator.close()
    config = write_config(tmp_path / "manual.toml", start, str(proc.ports["camera_uri"]))
    cfg = load_companion_config(config)
    gcs = GroundStation(ground_station)
    gcs.start()
    try:
        opts = RunOptions(connection=f"udpin:127.0.0.1:{companion_port}", pilot="manual", condition="int",
                          episodes=1, run_dir=tmp_path / "run", config_path=config, learn=False)
        result = run_episodes(cfg, opts)
    finally:
        gcs.stop.set()
        gcs.join(2.0)
    record = result.records[0]
    assert gcs.offboard_s is not None and gcs.sent_held > 0, "the ground station never held the button"
    assert record.outcome == "timeout" and record.steps == MAX_STEPS, record

    sent, motion = read_tlog(tmp_path / "run" / "session.tlog")
    held_steps = [sp for sp, held in sent if held]
    flags = [held for _, held in sent]
    first = flags.index(True)
    assert not any(flags[:first]) and all(flags[first:first + len(held_steps)]) and not flags[-1]  # policy, person, policy
    expected = CommandMapper(cfg.commands).to_setpoint(JoystickCommand(roll=0.0, pitch=PITCH, yaw=0.0, throttle=THROTTLE))
    assert record.interventions == 1
    # a step of the take-over on stale telemetry or without its camera frame (a busy machine) is
    # not recorded (the stale one holds instead); the episode's notes count them
    gaps = gap_steps(record.notes)
    assert len(held_steps) - gaps <= record.human_samples <= len(held_steps), (record.notes, len(held_steps))
    assert record.human_samples >= int(0.7 * HOLD_FOR_S * cfg.session.control_rate_hz)
    person = [sp for sp in held_steps  # the person's sticks went out, within the tick
              if (sp.vx, sp.vy, sp.vz) == pytest.approx((expected.forward_m_s, expected.right_m_s, expected.down_m_s), abs=1e-6)]
    assert len(held_steps) - len(person) <= gaps

    with (tmp_path / "run" / "human.csv").open(newline="") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == record.human_samples
    assert {r["source"] for r in rows} == {"intervention"}
    steps = [int(r["step"]) for r in rows]  # one take-over, but for its gaps
    assert steps == sorted(steps) and len(set(range(steps[0], steps[-1] + 1)) - set(steps)) <= gaps
    assert all(float(r["pitch"]) == pytest.approx(PITCH) and float(r["throttle"]) == pytest.approx(THROTTLE) for r in rows)
    # The vehicle follows: over the last 0.8 s of the take-over it flies the sticks' velocity.
    t_end = held_steps[-1]._timestamp
    settled = [(fwd, down) for t, fwd, down in motion if t_end - 0.8 <= t <= t_end]
    assert len(settled) >= 5
    for fwd, down in settled:
        assert fwd == pytest.approx(expected.forward_m_s, rel=0.25)
        assert down == pytest.approx(expected.down_m_s, rel=0.25)
