"""The estimator's local frame (``[sitl.estimator] height_offset_m``): PX4's origin is where its
estimator started, not the ground (on the ground real PX4 read heights of -1.0 to +1.3 m).

Reported LOCAL_POSITION_NED z = true z - offset, HOME_POSITION's x, y, z in that frame, LOCAL_NED
position setpoints read in it; GLOBAL_POSITION_INT, the control surface and the camera stay true.
"""

from __future__ import annotations

import pytest
from pymavlink.dialects.v20 import common as M

from companion.simulator import start_sitl
from sitl.config import SitlConfig
from sitl.control_surface import truth
from sitl.handler import MessageHandler
from sitl.modes import Mode
from sitl.offboard import FRAME_BODY_NED, FRAME_LOCAL_NED, FRAME_LOCAL_OFFSET_NED, TargetFields
from sitl.personality import make_vehicle
from sitl.telemetry import (
    TelemetryScheduler,
    global_position_int,
    home_position,
    local_position_ned,
)
from sitl.vehicle import SimVehicle
from tests.mav_client import MavTestClient

pytestmark = pytest.mark.realtime  # flies in real time: a higher priority where allowed

POSITION_ONLY = 0b110111111000
F32 = 1e-6  # MAVLink carries float32


def with_offset(offset_m: float) -> SitlConfig:
    return SitlConfig.model_validate({"estimator": {"height_offset_m": offset_m}})


def goto(v: SimVehicle, target: TargetFields, seconds: float) -> None:
    v.offboard_setpoint(target)
    v.request_mode(Mode.OFFBOARD)
    for i in range(round(seconds / v.dynamics.dt_s)):
        if i % 12 == 0:
            v.offboard_setpoint(target)
        v.step()


def packed(msg: M.MAVLink_message) -> bytes:
    return msg.pack(M.MAVLink(None, 1, 1))


def test_the_default_is_px4s_observed_home_height() -> None:
    v = SimVehicle(SitlConfig())
    assert v.height_offset_m == 0.7
    assert local_position_ned(v).z == pytest.approx(-0.7, abs=F32)


@pytest.mark.parametrize("offset", [0.7, -1.0, 1.3])
def test_on_the_ground_the_height_reads_the_offset_and_home_is_at_it(offset: float) -> None:
    v = SimVehicle(with_offset(offset))
    assert v.state.position_ned_m[2] == pytest.approx(0.0, abs=1e-3)  # the truth: on the ground
    assert local_position_ned(v).z == pytest.approx(v.state.position_ned_m[2] - offset, abs=F32)
    home = home_position(v)
    assert (home.x, home.y, home.z) == pytest.approx((*v.home_ned_m[:2], -offset), abs=F32)
    gpi = global_position_int(v)
    assert gpi.relative_alt == 0 and gpi.alt == 488_000  # AMSL and above home: true
    assert home.altitude == 488_000
    assert truth(v)["vehicle_ned"][2] == pytest.approx(0.0, abs=1e-3)


def test_a_local_ned_position_setpoint_is_read_in_the_reported_frame() -> None:
    offset = 0.7
    v = SimVehicle(with_offset(offset))
    v.arm()
    n, e, _ = v.state.position_ned_m
    goto(v, TargetFields(FRAME_LOCAL_NED, POSITION_ONLY, n, e, -(offset + 2.0), 0, 0, 0, 0, 0), 10.0)
    assert -v.state.position_ned_m[2] == pytest.approx(2.0, abs=0.05)  # true height 2 m
    assert -local_position_ned(v).z == pytest.approx(2.0 + offset, abs=0.05)
    assert global_position_int(v).relative_alt == pytest.approx(2000, abs=50)
    assert v.camera_state.position_ned_m == v.state.position_ned_m  # the camera renders the truth


def test_relative_and_body_frames_are_moved_only_where_the_position_is_absolute() -> None:
    v = SimVehicle(with_offset(0.7))
    v.reset_episode(seed=3)
    z0 = v.state.position_ned_m[2]
    v.offboard_setpoint(TargetFields(FRAME_LOCAL_OFFSET_NED, POSITION_ONLY, 0, 0, -1.0, 0, 0, 0, 0, 0))
    assert v.status.latest_offboard_sp.position_ned_m[2] == z0 - 1.0  # 1 m above where it is: no offset
    v.offboard_setpoint(TargetFields(FRAME_BODY_NED, POSITION_ONLY, 0, 0, -5.0, 0, 0, 0, 0, 0))
    assert v.status.latest_offboard_sp.position_ned_m[2] == -5.0 + 0.7  # from the origin, as LOCAL_NED
    v.offboard_setpoint(TargetFields(FRAME_BODY_NED, 0x5C7, 0, 0, 0, 0, 0, 0.5, 0, 0))
    assert v.status.latest_offboard_sp.velocity_ned_m_s[2] == 0.5  # velocities are not moved


def test_offset_zero_reports_the_truth_exactly() -> None:
    v = SimVehicle(with_offset(0.0))
    v.reset_episode(seed=4)
    for _ in range(200):
        v.step()
    s = v.state
    expected = M.MAVLink_local_position_ned_message(v.time_boot_ms, *s.position_ned_m, *s.velocity_ned_m_s)
    assert packed(local_position_ned(v)) == packed(expected)
    assert home_position(v).z == v.home_ned_m[2]
    target = TargetFields(FRAME_LOCAL_NED, POSITION_ONLY, 1.0, 2.0, -3.0, 0, 0, 0, 0, 0)
    v.offboard_setpoint(target)
    assert v.status.latest_offboard_sp.position_ned_m == (1.0, 2.0, -3.0)


def test_the_ardupilot_personality_has_its_origin_at_home() -> None:
    cfg = SitlConfig.model_validate({"personality": {"autopilot": "ardupilot"}, "estimator": {"height_offset_m": 0.7}})
    v = make_vehicle(cfg)
    assert v.height_offset_m == 0.0
    assert local_position_ned(v).z == pytest.approx(v.state.position_ned_m[2], abs=F32)
    assert home_position(v).z == 0.0


def test_request_message_answers_home_position_in_the_reported_frame() -> None:
    v = SimVehicle(SitlConfig())
    handler = MessageHandler(v, TelemetryScheduler(), None)
    req = M.MAVLink_command_long_message(1, 1, M.MAV_CMD_REQUEST_MESSAGE, 0, M.MAVLINK_MSG_ID_HOME_POSITION, 0, 0, 0, 0, 0, 0)
    ack, home = (o.message for o in handler.handle(req).replies)
    assert ack.get_type() == "COMMAND_ACK" and ack.result == M.MAV_RESULT_ACCEPTED
    assert home.get_type() == "HOME_POSITION" and home.z == pytest.approx(-0.7, abs=F32)


@pytest.mark.e2e
def test_over_mavlink_home_position_local_position_and_lndmc() -> None:
    """One check through the real process and sockets, with the defaults."""
    client = MavTestClient()
    sitl = start_sitl(client.port, clock="realtime", camera=False, extra_args=["--speed", "4"])
    try:
        client.wait_for(lambda m: m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 1)
        lpos = client.wait_for(lambda m: m.get_type() == "LOCAL_POSITION_NED")
        assert lpos.z == pytest.approx(-0.7, abs=0.01)
        assert client.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_HOME_POSITION) == M.MAV_RESULT_ACCEPTED
        home = client.wait_for(lambda m: m.get_type() == "HOME_POSITION")
        assert home.z == pytest.approx(-0.7, abs=F32) and home.altitude == 488_000
        gpi = client.wait_for(lambda m: m.get_type() == "GLOBAL_POSITION_INT")
        assert abs(gpi.relative_alt) < 20
        client.send(M.MAVLink_param_set_message(1, 1, b"LNDMC_Z_VEL_MAX", 0.3, M.MAV_PARAM_TYPE_REAL32))
        pv = client.wait_for(lambda m: m.get_type() == "PARAM_VALUE" and m.param_id == "LNDMC_Z_VEL_MAX")
        assert pv.param_value == pytest.approx(0.3)
        client.send(M.MAVLink_param_request_read_message(1, 1, b"LNDMC_Z_VEL_MAX", -1))
        pv = client.wait_for(lambda m: m.get_type() == "PARAM_VALUE" and m.param_id == "LNDMC_Z_VEL_MAX")
        assert pv.param_value == pytest.approx(0.3)
    finally:
        sitl.stop()
        client.close()
