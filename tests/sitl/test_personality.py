"""The ArduCopter personality in process: HEARTBEAT, modes, pre-arm settling, GUIDED take-off,
body-velocity semantics, GUID_TIMEOUT, BRAKE, LAND, parameters; the PX4 one stays as it was."""

from __future__ import annotations

import math

import pytest
from pymavlink.dialects.v20 import common as M

from colcommon.errors import ConfigError
from sitl.cli import build_config
from sitl.config import SitlConfig
from sitl.modes import Mode
from sitl.offboard import (
    FRAME_BODY_NED,
    FRAME_BODY_OFFSET_NED,
    FRAME_LOCAL_NED,
    FRAME_LOCAL_OFFSET_NED,
    TargetFields,
)
from sitl.params import encode_value
from sitl.personality import CopterMode, CopterVehicle, copter_setpoint, make_vehicle
from sitl.telemetry import heartbeat
from sitl.vehicle import SimVehicle
from tests.sitl.test_vehicle import body_velocity, run_s

VELOCITY = 0x5C7  # the companion's: velocity + yaw rate
VELOCITY_AUTO_YAW = 0xDC7  # velocity only: ArduCopter turns to face its travel
POSITION = 0x9F8  # position + yaw (the companion's)


def copter(settle_s: float = 2.0) -> CopterVehicle:
    cfg = SitlConfig().model_copy(update={"personality": SitlConfig().personality.model_copy(
        update={"autopilot": "ardupilot", "prearm_settle_s": settle_s})})
    v = make_vehicle(cfg)
    assert isinstance(v, CopterVehicle)
    return v


def settled(v: CopterVehicle) -> CopterVehicle:
    run_s(v, v.commander.settle_s + 0.1)
    v.events.clear()
    return v


def flying_guided(v: CopterVehicle, alt_m: float = 3.0) -> CopterVehicle:
    settled(v)
    assert v.request_copter_mode(CopterMode.GUIDED)[0] == M.MAV_RESULT_ACCEPTED
    assert v.arm()[0] == M.MAV_RESULT_ACCEPTED
    assert v.takeoff(alt_m)[0] == M.MAV_RESULT_ACCEPTED
    run_s(v, 6.0)
    return v


def test_heartbeat_says_ardupilot_with_copter_mode_numbers() -> None:
    v = copter()
    hb = heartbeat(v)
    assert hb.autopilot == M.MAV_AUTOPILOT_ARDUPILOTMEGA and hb.type == M.MAV_TYPE_QUADROTOR
    assert hb.custom_mode == 0  # boots in STABILIZE
    assert [int(m) for m in CopterMode] == [0, 4, 5, 6, 9, 17]
    assert v.sends_frame_marker is False  # no SYSTEM_TIME: no lockstep
    px4 = make_vehicle(SitlConfig())
    assert type(px4) is SimVehicle and heartbeat(px4).autopilot == M.MAV_AUTOPILOT_PX4


def test_arming_and_guided_are_refused_while_the_ekf_settles_with_prearm_reasons() -> None:
    v = copter(settle_s=2.0)
    assert v.arm() == (M.MAV_RESULT_FAILED, "")
    texts = [t for _, t in v.events]
    assert "Arm: Need Position Estimate" in texts and any(t.startswith("PreArm:") for t in texts)
    result, why = v.request_copter_mode(CopterMode.GUIDED)
    assert result == M.MAV_RESULT_FAILED and "requires position" in why
    settled(v)
    assert v.request_copter_mode(CopterMode.GUIDED)[0] == M.MAV_RESULT_ACCEPTED
    assert v.arm()[0] == M.MAV_RESULT_ACCEPTED and v.armed


def test_takeoff_only_armed_in_guided() -> None:
    v = settled(copter())
    assert v.takeoff(3.0)[0] == M.MAV_RESULT_FAILED  # disarmed
    assert v.arm()[0] == M.MAV_RESULT_ACCEPTED  # STABILIZE arms
    assert v.takeoff(3.0)[0] == M.MAV_RESULT_FAILED  # but does not take off
    assert v.copter_mode is CopterMode.STABILIZE and v.landed


def test_guided_takeoff_climbs_to_param7_above_home_and_stays_guided() -> None:
    v = flying_guided(copter(), alt_m=3.0)
    assert v.copter_mode is CopterMode.GUIDED and heartbeat(v).custom_mode == 4
    assert -v.state.position_ned_m[2] == pytest.approx(3.0, abs=0.2)
    assert v.landed_state == M.MAV_LANDED_STATE_IN_AIR


def test_arming_in_land_or_brake_is_refused() -> None:
    v = settled(copter())
    v.request_copter_mode(CopterMode.LAND)
    assert v.arm() == (M.MAV_RESULT_FAILED, "Arm: Mode not armable")
    assert v.request_copter_mode(99)[0] == M.MAV_RESULT_FAILED


def test_body_velocity_is_turned_by_the_heading_in_both_body_frames() -> None:
    yaw = math.pi / 2  # facing east
    for frame in (FRAME_BODY_NED, FRAME_BODY_OFFSET_NED):
        sp = copter_setpoint(TargetFields(frame, VELOCITY, 0, 0, 0, 1.0, 0.5, 0.2, 0, 0.1), (5.0, 6.0, -3.0), yaw, 5.0)
        assert sp.velocity_ned_m_s == pytest.approx((-0.5, 1.0, 0.2))  # forward -> east, right -> south
        assert math.isnan(sp.position_ned_m[0]) and sp.yaw_rate_rad_s == 0.1
    local = copter_setpoint(TargetFields(FRAME_LOCAL_NED, VELOCITY, 0, 0, 0, 1.0, 0.5, 0.2, 0, 0), (0, 0, 0), yaw, 5.0)
    assert local.velocity_ned_m_s == pytest.approx((1.0, 0.5, 0.2))


def test_positions_per_frame_as_arducopter_documents_them() -> None:
    here, yaw = (5.0, 6.0, -3.0), math.pi / 2

    def target(frame: int):  # type: ignore[no-untyped-def]
        return copter_setpoint(TargetFields(frame, POSITION, 1.0, 2.0, -1.0, 0, 0, 0, 0.3, 0), here, yaw, 5.0)

    assert target(FRAME_LOCAL_NED).position_ned_m == pytest.approx((1.0, 2.0, -1.0))  # from the EKF origin
    assert target(FRAME_BODY_NED).position_ned_m == pytest.approx((1.0, 2.0, -1.0))  # also from the origin
    assert target(FRAME_LOCAL_OFFSET_NED).position_ned_m == pytest.approx((6.0, 8.0, -4.0))
    assert target(FRAME_BODY_OFFSET_NED).position_ned_m == pytest.approx((3.0, 7.0, -4.0))  # forward = east
    assert target(FRAME_LOCAL_NED).yaw_rad == pytest.approx(0.3)
    assert target(FRAME_BODY_OFFSET_NED).yaw_rad == pytest.approx(0.3 + yaw)  # relative only here


def test_without_yaw_or_yaw_rate_the_copter_faces_its_travel_and_partial_groups_count_as_ignored() -> None:
    sp = copter_setpoint(TargetFields(FRAME_LOCAL_NED, VELOCITY_AUTO_YAW, 0, 0, 0, 0.0, 2.0, 0, 0, 0), (0, 0, 0), 0.0, 5.0)
    assert sp.yaw_rad == pytest.approx(math.pi / 2)
    from sitl.offboard import SetpointRejected

    with pytest.raises(SetpointRejected):  # x ignored: the whole position group is, and nothing is left
        copter_setpoint(TargetFields(FRAME_LOCAL_NED, POSITION | 1 | 0x38, 1, 2, 3, 0, 0, 0, 0, 0), (0, 0, 0), 0.0, 5.0)
    with pytest.raises(SetpointRejected, match="frame"):
        copter_setpoint(TargetFields(12, VELOCITY, 0, 0, 0, 1, 0, 0, 0, 0), (0, 0, 0), 0.0, 5.0)


def test_guided_flies_body_velocity_then_stops_after_guid_timeout() -> None:
    v = flying_guided(copter())
    n0 = v.state.position_ned_m[0]
    heading = v.state.attitude_rad[2]
    run_s(v, 2.0, lambda v: v.offboard_setpoint(body_velocity(forward=1.0)))
    moved = v.state.position_ned_m[0] - n0, v.state.position_ned_m[1]
    assert math.hypot(*moved) > 1.0 and abs(math.atan2(moved[1] - v.home_ned_m[1], moved[0]) - heading) < 0.3
    run_s(v, 5.0)  # no setpoints: GUID_TIMEOUT (3 s) stops the vehicle, still in GUIDED
    assert v.copter_mode is CopterMode.GUIDED
    assert math.hypot(*v.state.velocity_ned_m_s[:2]) < 0.2


def test_targets_outside_guided_are_ignored() -> None:
    v = flying_guided(copter())
    v.request_copter_mode(CopterMode.BRAKE)
    assert v.offboard_setpoint(body_velocity(forward=2.0)) is False


def test_brake_holds_position_without_sticks() -> None:
    v = flying_guided(copter())
    run_s(v, 1.0, lambda v: v.offboard_setpoint(body_velocity(forward=2.0, down=0.0)))
    assert v.request_copter_mode(CopterMode.BRAKE)[0] == M.MAV_RESULT_ACCEPTED
    run_s(v, 4.0)
    before = v.state.position_ned_m
    run_s(v, 3.0)
    assert math.dist(before, v.state.position_ned_m) < 0.3 and v.mode is Mode.AUTO_LOITER


def test_nav_land_switches_to_land_which_lands_and_disarms() -> None:
    v = flying_guided(copter())
    assert v.land()[0] == M.MAV_RESULT_ACCEPTED and v.copter_mode is CopterMode.LAND
    run_s(v, 10.0)
    assert v.landed and not v.armed and heartbeat(v).custom_mode == 9


def test_landed_in_guided_stays_on_the_ground_until_a_takeoff() -> None:
    v = flying_guided(copter(), alt_m=1.0)
    run_s(v, 6.0, lambda v: v.offboard_setpoint(body_velocity(down=0.7)))
    assert v.landed and v.touchdown is not None
    run_s(v, 2.0, lambda v: v.offboard_setpoint(body_velocity(forward=1.0, down=-0.5)))  # ignored on the ground
    assert v.landed
    assert v.takeoff(2.0)[0] == M.MAV_RESULT_ACCEPTED
    run_s(v, 5.0)
    assert v.touchdown is None and -v.state.position_ned_m[2] == pytest.approx(2.0, abs=0.2)


def test_rtl_returns_home_and_lands() -> None:
    v = flying_guided(copter())
    run_s(v, 3.0, lambda v: v.offboard_setpoint(body_velocity(forward=1.5)))
    assert v.request_copter_mode(CopterMode.RTL)[0] == M.MAV_RESULT_ACCEPTED
    run_s(v, 25.0)
    assert v.landed and math.dist(v.state.position_ned_m[:2], v.home_ned_m[:2]) < 0.6


def test_parameters_have_arducopter_names_and_drive_the_cascade() -> None:
    v = copter()
    names = {p.name for p in v.params}
    assert {"WPNAV_SPEED", "ANGLE_MAX", "LAND_SPEED", "GUID_TIMEOUT", "DISARM_DELAY", "SYSID_THISMAV"} <= names
    assert not names & {"MPC_XY_VEL_MAX", "COM_OF_LOSS_T", "MIS_TAKEOFF_ALT"}
    assert v.params.get("WPNAV_SPEED") == pytest.approx(500.0)  # cm/s
    assert v.params.get("GUID_TIMEOUT") == pytest.approx(3.0)
    assert v.set_param("WPNAV_SPEED", encode_value(250.0, M.MAV_PARAM_TYPE_REAL32))
    assert v.params.get("MPC_XY_VEL_MAX") == pytest.approx(2.5)  # what the vehicle's own code reads
    assert v.controller.cfg.max_speed_xy_m_s == pytest.approx(2.5)
    assert not v.set_param("MPC_XY_VEL_MAX", 1.0)


def test_episode_reset_leaves_the_copter_hovering_in_brake() -> None:
    v = copter()
    v.reset_episode(seed=3)
    assert v.armed and v.copter_mode is CopterMode.BRAKE and not v.landed


def test_lockstep_is_refused_for_the_ardupilot_personality() -> None:
    with pytest.raises(ConfigError, match="lockstep"):
        build_config(SitlConfig(), clock="lockstep", autopilot="ardupilot")
    assert build_config(SitlConfig(), clock="realtime", autopilot="ardupilot").personality.autopilot == "ardupilot"
