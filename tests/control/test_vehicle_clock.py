"""Real time by the vehicle's clock: an autopilot's SITL run faster than real time is flown at the
control rate of its own time, the rendered camera draws at its rate of that time, and scripts and
tests wait on it by its stamps. Clocks are injected: no wall-clock timing in these tests."""

from __future__ import annotations

import struct
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest
from pymavlink import mavutil

from companion.config import SessionConfig
from companion.control.link_port import VehicleClockTicker
from companion.link.tlog import TlogWriter
from companion.testing.vehicle_time import TlogClock, VehicleClock, wall_cap_s
from companion.vision.rendered import RenderedCamera
from sitl.config import CameraConfig, WorldConfig
from tests.vision.test_rendered import Clock, snapshot


class FastVehicle:
    """A vehicle whose clock runs ``speedup`` times the (fake) wall clock."""

    def __init__(self, speedup: float) -> None:
        self.speedup, self.wall_s, self.frozen = speedup, 0.0, False
        self.vehicle_ms = 50_000.0

    def sleep(self, dt_s: float) -> None:
        self.wall_s += dt_s
        if not self.frozen:
            self.vehicle_ms += 1000.0 * dt_s * self.speedup

    def ms(self) -> int:
        return int(self.vehicle_ms)


@pytest.mark.parametrize("speedup", [1.0, 4.0, 5.0])
def test_steps_come_every_control_period_of_the_vehicles_time(speedup: float) -> None:
    v = FastVehicle(speedup)
    ticker = VehicleClockTicker(10.0, v.ms, poll_s=0.001, clock=lambda: v.wall_s, sleep=v.sleep)
    for _ in range(21):
        ticker.wait()
    assert ticker.periods_s == pytest.approx([0.1] * 20, abs=0.002 * speedup + 1e-9)  # vehicle time
    assert v.wall_s == pytest.approx(2.1 / speedup, rel=0.05)  # the wall time it took


def test_a_late_step_starts_the_next_period_from_now_and_a_frozen_vehicle_is_not_waited_for_long() -> None:
    v = FastVehicle(1.0)
    ticker = VehicleClockTicker(10.0, v.ms, poll_s=0.001, patience_s=1.0, clock=lambda: v.wall_s, sleep=v.sleep)
    ticker.wait()
    v.vehicle_ms += 350  # the companion was busy for 3.5 periods
    ticker.wait()
    assert ticker.periods_s[-1] == pytest.approx(0.35, abs=0.002)  # no wait: late already
    ticker.wait()
    assert ticker.periods_s[-1] == pytest.approx(0.1, abs=0.002)  # then a period, not a burst
    v.frozen = True
    start = v.wall_s
    ticker.wait()  # the vehicle's clock stands: at most patience_s, then the link's loss rule decides
    assert v.wall_s - start == pytest.approx(1.0, abs=0.01)


def test_the_session_is_paced_by_the_wall_clock_unless_told() -> None:
    assert SessionConfig().clock == "wall"
    assert SessionConfig(clock="vehicle").clock == "vehicle"
    with pytest.raises(ValueError):
        SessionConfig(clock="sundial")


def test_by_the_vehicles_clock_the_camera_draws_a_frame_per_period_of_its_time() -> None:
    state = {"snap": snapshot(1.0, 1.0, -4.0, t_ms=1000, received_s=10.0)}
    clock = Clock(10.0)
    cam = RenderedCamera(lambda: state["snap"], CameraConfig(), WorldConfig(), rate_hz=30.0, clock=clock,
                         vehicle_clock=True)
    drawn = []
    for k in range(40):  # telemetry every 10 ms of vehicle time, however fast the wall clock goes
        state["snap"] = replace(state["snap"], time_boot_ms=1000 + 10 * k, received_s=10.0)
        frame = cam.step()
        if frame is not None:
            drawn.append(frame.time_boot_ms)
    assert drawn == [1000, 1040, 1080, 1120, 1160, 1200, 1240, 1280, 1320, 1360]  # 33.3 ms apart at least
    wall = RenderedCamera(lambda: state["snap"], CameraConfig(), WorldConfig(), rate_hz=30.0, clock=clock)
    state["snap"] = replace(state["snap"], time_boot_ms=2000)
    assert wall.step() is not None
    state["snap"] = replace(state["snap"], time_boot_ms=2010)
    assert wall.step() is not None  # by the wall clock the loop's own period paces it instead


# ----- the vehicle's time for scripts and tests (companion/testing/vehicle_time.py) ---------------
def _attitude(ms: int, component: int = 1) -> Any:
    mav = mavutil.mavlink.MAVLink(None, srcSystem=1, srcComponent=component)
    msg = mav.attitude_encode(ms, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    msg.pack(mav)
    return msg


def test_the_vehicle_clock_counts_its_stamps_through_late_messages_and_a_reboot() -> None:
    clock = VehicleClock()
    for ms in (40_000, 40_500, 40_480, 41_000):  # 40_480: a stream stamped earlier, arriving later
        clock.observe(_attitude(ms))
    assert clock.seconds == pytest.approx(1.0)
    clock.observe(_attitude(300))  # rebooted: its boot clock starts again
    clock.observe(_attitude(1_300))
    assert clock.seconds == pytest.approx(2.0)
    clock.observe(mavutil.mavlink.MAVLink_heartbeat_message(2, 3, 0, 0, 0, 3))  # no stamp: nothing
    assert clock.seconds == pytest.approx(2.0)


def test_the_tlog_clock_follows_a_growing_tlog_and_counts_only_the_vehicles_packets(tmp_path: Path) -> None:
    path = tmp_path / "session.tlog"
    writer = TlogWriter(path, flush_every=1)
    tlog = TlogClock(path)
    assert tlog.seconds() == 0.0  # not written yet
    for k in range(11):  # 10 s of the vehicle's time in 2.5 s of the wall's: 4x
        writer.write(_attitude(10_000 + 1000 * k).get_msgbuf(), wall_time_s=100.0 + 0.25 * k)
        writer.write(_attitude(99_000).get_msgbuf(), sent=True, wall_time_s=100.0 + 0.25 * k)  # ours: not the vehicle's
        writer.write(_attitude(5, component=100).get_msgbuf(), wall_time_s=100.0 + 0.25 * k)  # its camera's
        if k == 4:
            assert tlog.seconds() == pytest.approx(4.0)
    record = _attitude(21_000).get_msgbuf()
    with path.open("ab") as f:  # half a record, as a reader may find it between two flushes
        f.write(struct.pack(">Q", int(103e6)) + record[:10])
    assert tlog.seconds() == pytest.approx(10.0)
    with path.open("ab") as f:
        f.write(record[10:])
    assert tlog.seconds() == pytest.approx(11.0)
    writer.close()
    assert tlog.speed() == {"wall_s": 3.0, "vehicle_s": 11.0, "speed": pytest.approx(3.667, abs=1e-3)}


def test_a_wait_on_the_vehicles_time_is_capped_by_the_wall_clock_generously() -> None:
    assert wall_cap_s(20.0) == 70.0  # a vehicle at a third of real time still passes 20 s of its own
