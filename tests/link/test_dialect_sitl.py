"""The link and the session's sequences against the SITL in both personalities, over MAVLink:
who refused what and why, take-off, hold and the end-of-run landing, per dialect."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from pymavlink import mavutil

from companion.config import LinkConfig
from companion.control.sequences import arm_when_ready, leave_safe, take_off
from companion.errors import CommandRejected
from companion.link.dialect import Dialect, dialect_for
from companion.link.mavlink_link import MavlinkLink
from companion.simulator import start_sitl
from tests.conftest import free_port

pytestmark = [pytest.mark.realtime, pytest.mark.e2e, pytest.mark.timeout(600)]  # real time, on a shared machine
SETTLE_S = 3.0


@pytest.fixture(params=["px4", "ardupilot"])
def personality(request: pytest.FixtureRequest) -> str:
    return str(request.param)


@pytest.fixture
def link(personality: str, tmp_path: Path) -> Iterator[MavlinkLink]:
    """A fresh real-time SITL of the personality (just booted) and a connected link to it."""
    config = tmp_path / "sitl.toml"
    config.write_text(f"[sitl.personality]\nprearm_settle_s = {SETTLE_S}\n")
    port = free_port()
    sitl = start_sitl(port, clock="realtime", config=config, camera=False, timeout_s=120.0,
                      extra_args=["--autopilot", personality])
    link = MavlinkLink(LinkConfig(connection=f"udpin:127.0.0.1:{port}"), tlog_path=tmp_path / "link.tlog")
    try:
        link.connect(timeout_s=20.0)
        yield link
    finally:
        link.close()
        sitl.stop()


def until(test: Callable[[], bool], timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if test():
            return True
        time.sleep(0.05)
    return test()


def sent_set_modes(tlog: Path) -> int:
    log = mavutil.mavlink_connection(str(tlog), dialect="common")
    n = 0
    try:
        while (msg := log.recv_match(type="COMMAND_LONG")) is not None:
            n += msg.command == mavutil.mavlink.MAV_CMD_DO_SET_MODE
    finally:
        log.close()
    return n


def test_the_link_tells_the_dialect_from_the_heartbeat(link: MavlinkLink, personality: str) -> None:
    snap = link.state()
    assert snap is not None
    assert snap.autopilot == {"px4": "PX4", "ardupilot": "ARDUPILOTMEGA"}[personality]
    assert dialect_for(snap.autopilot).name == {"px4": "PX4", "ardupilot": "ArduPilot"}[personality]
    # ArduCopter sends little until asked: the rates requested on connect bring position in
    assert until(lambda: link.state().position_valid and link.state().attitude_valid, 5.0)  # type: ignore[union-attr]


def test_a_mode_the_autopilot_lacks_is_refused_by_the_companion_without_asking(link: MavlinkLink, personality: str,
                                                                                tmp_path: Path) -> None:
    foreign = "OFFBOARD" if personality == "ardupilot" else "GUIDED"
    with pytest.raises(CommandRejected) as info:
        link.set_mode(foreign)
    assert info.value.origin == "companion" and "without asking the vehicle" in str(info.value)
    assert "vehicle rejected" not in str(info.value)
    link.close()
    assert sent_set_modes(tmp_path / "link.tlog") == 0


def test_a_vehicle_refusal_carries_the_vehicles_reason(link: MavlinkLink, personality: str) -> None:
    if personality == "ardupilot":  # just booted: the EKF settles, arming is refused with PreArm reasons
        with pytest.raises(CommandRejected) as info:
            link.arm()
        assert "Arm: Need Position Estimate" in info.value.reasons
    else:  # OFFBOARD without a setpoint stream
        with pytest.raises(CommandRejected) as info:
            link.set_mode("OFFBOARD")
        assert any("stream setpoints first" in r for r in info.value.reasons)
    assert info.value.origin == "vehicle" and "vehicle says" in str(info.value)


def test_arducopter_takes_off_only_in_guided_and_the_hint_says_so(link: MavlinkLink, personality: str) -> None:
    if personality != "ardupilot":
        pytest.skip("PX4 takes off from any mode")
    arm_when_ready(link, timeout_s=SETTLE_S + 10)  # STABILIZE arms once settled
    with pytest.raises(CommandRejected, match="GUIDED") as info:
        link.takeoff(2.0)
    assert info.value.result == "FAILED"
    link.disarm()


def height_above_home(link: MavlinkLink) -> float:
    """PX4's local z = 0 is not the ground (our SITL's PX4 reports the ground 0.7 m up): from home."""
    snap = link.state()
    assert snap is not None
    home_down = snap.home_ned_m[2] if snap.home_ned_m is not None else 0.0
    return home_down - snap.position_ned_m[2]


def test_take_off_hold_and_end_of_run_landing_per_dialect(link: MavlinkLink, personality: str) -> None:
    dialect: Dialect = dialect_for(link.state().autopilot)  # type: ignore[union-attr]
    take_off(link, dialect, 2.0, arm_timeout_s=SETTLE_S + 10)  # waits out the settling, if any
    assert until(lambda: height_above_home(link) > 1.8, 15.0)
    after_takeoff = {"px4": "AUTO.LOITER", "ardupilot": "GUIDED"}[personality]
    assert until(lambda: link.state().mode == after_takeoff, 5.0)  # type: ignore[union-attr]
    link.set_mode(dialect.hold_mode)
    assert until(lambda: dialect.is_hold(link.state().mode), 3.0)  # type: ignore[union-attr]
    assert leave_safe(link, dialect, "land") == dialect.land_mode
    assert until(lambda: not link.state().armed, 20.0)  # type: ignore[union-attr]
    assert link.state().landed_state == "ON_GROUND"  # type: ignore[union-attr]
    assert leave_safe(link, dialect, "land") == "disarmed"
