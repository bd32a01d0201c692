"""The MAVSDK link against the same fake vehicle (MAVSDK 4's native library, real sockets)."""

from __future__ import annotations

import time
from collections.abc import Iterator

import pytest
from pymavlink.dialects.v20 import common as mavlink

from companion.config import LinkConfig
from companion.errors import CommandRejected, ConfigError, LinkLost
from companion.link import ManualControlMessage, open_link
from companion.link.mavsdk_link import MavsdkLink, mavsdk_url
from companion.msg.setpoint import VelocitySetpoint
from companion.testing import FakeVehicle
from companion.testing.link_contract import run_link_contract
from tests.conftest import wait_until as _until

pytest.importorskip("mavsdk")


@pytest.fixture
def link(fake: FakeVehicle) -> Iterator[MavsdkLink]:
    cfg = LinkConfig(connection=fake.connection_string, link_lost_s=0.4)
    mavsdk_link = open_link(cfg, kind="mavsdk")
    assert isinstance(mavsdk_link, MavsdkLink)
    mavsdk_link.connect(timeout_s=5.0)
    yield mavsdk_link
    mavsdk_link.close()


@pytest.mark.parametrize(
    ("connection", "url"),
    [
        ("udpin:0.0.0.0:14540", "udpin://0.0.0.0:14540"),
        ("udpout:127.0.0.1:14580", "udpout://127.0.0.1:14580"),
        ("tcp:127.0.0.1:5760", "tcpout://127.0.0.1:5760"),
        ("tcpin:0.0.0.0:5760", "tcpin://0.0.0.0:5760"),
        ("/dev/ttyACM0,921600", "serial:///dev/ttyACM0:921600"),
    ],
)
def test_connection_strings_become_mavsdk_urls(connection: str, url: str) -> None:
    assert mavsdk_url(connection, 57600) == url


def test_tlog_is_refused_with_a_pointer_to_the_pymavlink_link(tmp_path) -> None:
    with pytest.raises(ConfigError, match="pymavlink"):
        open_link(LinkConfig(), kind="mavsdk", tlog_path=tmp_path / "x.tlog")


def test_mavsdk_link_meets_the_contract_against_the_fake(link) -> None:
    names = run_link_contract(link)
    assert "arm_disarm" in names and "frames" in names


def test_body_velocity_goes_out_in_body_frame_with_yaw_rate_in_rad_s(fake, link) -> None:
    link.set_mode("OFFBOARD")
    assert fake.mode == "OFFBOARD"
    link.send_velocity_body(VelocitySetpoint(1.25, -0.5, 0.2, 0.4))
    msg = fake.wait_for("SET_POSITION_TARGET_LOCAL_NED", predicate=lambda m: m.vx > 1.0)
    assert (msg.coordinate_frame, msg.type_mask) == (mavlink.MAV_FRAME_BODY_NED, 0x5C7)
    assert (msg.vx, msg.vy, msg.vz) == pytest.approx((1.25, -0.5, 0.2))
    assert msg.yaw_rate == pytest.approx(0.4, rel=1e-4)


def test_arming_refusal_raises_command_rejected(fake, link) -> None:
    fake.set_arm_result("DENIED")
    with pytest.raises(CommandRejected) as info:
        link.arm()
    assert info.value.result == "DENIED"
    assert not fake.armed


def test_modes_mavsdk_cannot_select_are_refused(link) -> None:
    with pytest.raises(CommandRejected, match="UNSUPPORTED"):
        link.set_mode("ACRO")


def test_manual_control_from_a_ground_station_reaches_the_callback(fake, link) -> None:
    got: list[ManualControlMessage] = []
    link.on_manual_control(got.append)
    # A ground station streams; the link picks up a new sender within about half a second.
    deadline = time.monotonic() + 3.0
    while not got and time.monotonic() < deadline:
        fake.send_manual_control(x=-250, y=1000, z=0, r=0, buttons=0b10)
        fake.send_manual_control(x=5000)  # out of range: dropped
        time.sleep(0.05)
    assert got and (got[-1].axis("x"), got[-1].axis("y"), got[-1].buttons) == (-0.25, 1.0, 0b10)
    assert link.stats().manual_control_dropped >= 1


def test_link_loss_and_resume(fake, link) -> None:
    fake.go_silent()
    assert _until(lambda: not link.link_alive(), 2.0)
    with pytest.raises(LinkLost):
        link.send_velocity_body(VelocitySetpoint.zero())
    fake.resume()
    assert _until(link.link_alive, 3.0)
    link.send_velocity_body(VelocitySetpoint.zero())
    stats = link.stats()
    assert stats.link_losses >= 1 and stats.reconnections >= 1


def test_mavsdk_names_become_px4_and_mavlink_names() -> None:
    from mavsdk.plugins.telemetry import FlightMode, LandedState

    from companion.errors import LinkTimeout
    from companion.link.mavsdk_convert import (
        fold_flight_mode,
        fold_landed_state,
        initial_snapshot,
        translate_result,
    )

    snapshot = initial_snapshot(1, "PX4", 0.0)
    assert fold_flight_mode(snapshot, FlightMode.HOLD).mode == "AUTO.LOITER"
    assert fold_flight_mode(snapshot, FlightMode.OFFBOARD).mode == "OFFBOARD"
    assert fold_landed_state(snapshot, LandedState.TAKING_OFF).landed_state == "TAKEOFF"
    assert translate_result("arm", "COMMAND_DENIED").result == "DENIED"
    assert isinstance(translate_result("arm", "TIMEOUT"), LinkTimeout)
    assert isinstance(translate_result("arm", "NO_SYSTEM"), LinkLost)


def test_the_sitls_truth_and_origin_reach_the_mavsdk_link_at_the_asked_rate(fake, link) -> None:
    """MAVSDK's plugins carry no truth: the link asks for it by SET_MESSAGE_INTERVAL and reads
    HIL_STATE_QUATERNION and GPS_GLOBAL_ORIGIN raw, folded by the pymavlink link's rules."""
    from tests.link.test_true_pose import PX4_ORIGIN, hil_state, origin_message, quaternion

    results = link.request_rates({"HIL_STATE_QUATERNION": 30.0, "GPS_GLOBAL_ORIGIN": 1.0})
    assert results == {"HIL_STATE_QUATERNION": "ACCEPTED", "GPS_GLOBAL_ORIGIN": "ACCEPTED"}
    intervals = fake.requested_intervals_us()
    assert intervals[mavlink.MAVLINK_MSG_ID_HIL_STATE_QUATERNION] == pytest.approx(1e6 / 30.0)
    assert intervals[mavlink.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN] == pytest.approx(1e6)
    assert link.request_rates({"NO_SUCH_MESSAGE": 1.0}) == {"NO_SUCH_MESSAGE": "UNSUPPORTED"}
    hil = hil_state(3.0, -4.0, 5.0, quaternion(0.1, -0.2, 1.0), time_usec=12_345_678)
    assert _until(lambda: (fake.send_message(origin_message(*PX4_ORIGIN)), fake.send_message(hil),
                           (s := link.state()) is not None and s.true_pose is not None)[-1])
    pose = link.state().true_pose
    assert pose.source == "HIL_STATE_QUATERNION"
    assert pose.position_ned_m == pytest.approx((3.0, -4.0, -5.0), abs=0.01)
    assert pose.attitude_rad == pytest.approx((0.1, -0.2, 1.0), abs=1e-6)
