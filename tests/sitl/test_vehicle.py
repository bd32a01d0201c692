"""The simulated autopilot in process: arming, takeoff, offboard, failsafes, ground contact."""

from __future__ import annotations

import math

import pytest
from pymavlink.dialects.v20 import common as M

from sitl.commander import PREFLIGHT_DISARM_S
from sitl.config import SitlConfig
from sitl.modes import Mode
from sitl.offboard import FRAME_BODY_NED, TargetFields
from sitl.vehicle import SimVehicle


def run_s(v: SimVehicle, seconds: float, each_step=None) -> None:
    for _ in range(int(round(seconds / v.dynamics.dt_s))):
        if each_step is not None:
            each_step(v)
        v.step()


def body_velocity(forward: float = 0.0, right: float = 0.0, down: float = 0.0, yaw_rate: float = 0.0) -> TargetFields:
    return TargetFields(FRAME_BODY_NED, 0x5C7, 0, 0, 0, forward, right, down, 0, yaw_rate)


@pytest.fixture
def vehicle() -> SimVehicle:
    return SimVehicle(SitlConfig())


def test_starts_landed_disarmed_on_the_ground(vehicle: SimVehicle) -> None:
    assert not vehicle.armed and vehicle.landed
    assert vehicle.landed_state == M.MAV_LANDED_STATE_ON_GROUND
    assert vehicle.state.position_ned_m[2] == pytest.approx(0.0, abs=0.2)


def test_arm_takeoff_hold_land_disarm(vehicle: SimVehicle) -> None:
    assert vehicle.arm()[0] == M.MAV_RESULT_ACCEPTED
    assert vehicle.takeoff(math.nan)[0] == M.MAV_RESULT_ACCEPTED
    run_s(vehicle, 8.0)
    assert vehicle.mode is Mode.AUTO_LOITER
    assert -vehicle.state.position_ned_m[2] == pytest.approx(2.5, abs=0.15)
    assert not vehicle.landed
    assert vehicle.disarm()[0] == M.MAV_RESULT_DENIED  # not in the air without force
    assert vehicle.land()[0] == M.MAV_RESULT_ACCEPTED
    run_s(vehicle, 8.0)
    assert vehicle.landed and not vehicle.armed


def test_arming_again_after_a_landing_waits_for_the_preflight_timeout(vehicle: SimVehicle) -> None:
    """As PX4: the landed disarm needs a flight since arming; a vehicle armed on the ground (still in
    AUTO.LAND from the last landing) stays armed until COM_DISARM_PRFLT, not one step."""
    vehicle.arm()
    vehicle.takeoff(math.nan)
    run_s(vehicle, 8.0)
    vehicle.land()
    run_s(vehicle, 8.0)
    assert vehicle.mode is Mode.AUTO_LAND and not vehicle.armed
    assert vehicle.arm()[0] == M.MAV_RESULT_ACCEPTED
    run_s(vehicle, PREFLIGHT_DISARM_S - 1.0)
    assert vehicle.armed
    run_s(vehicle, 2.0)
    assert not vehicle.armed


def test_takeoff_needs_arming(vehicle: SimVehicle) -> None:
    assert vehicle.takeoff(math.nan)[0] == M.MAV_RESULT_TEMPORARILY_REJECTED


def test_offboard_refused_without_stream_then_flies_body_velocity(vehicle: SimVehicle) -> None:
    vehicle.reset_episode(seed=1)
    assert vehicle.request_mode(Mode.OFFBOARD)[0] == M.MAV_RESULT_DENIED
    vehicle.offboard_setpoint(body_velocity(forward=1.0))
    assert vehicle.request_mode(Mode.OFFBOARD)[0] == M.MAV_RESULT_ACCEPTED
    n0 = vehicle.state.position_ned_m[0]
    run_s(vehicle, 3.0, lambda v: v.offboard_setpoint(body_velocity(forward=1.0)))
    assert vehicle.mode is Mode.OFFBOARD
    assert vehicle.state.velocity_ned_m_s[0] == pytest.approx(1.0, abs=0.1)
    assert vehicle.state.position_ned_m[0] - n0 > 2.0


def test_offboard_loss_holds_then_lands(vehicle: SimVehicle) -> None:
    vehicle.reset_episode(seed=2)
    vehicle.offboard_setpoint(body_velocity())
    vehicle.request_mode(Mode.OFFBOARD)
    run_s(vehicle, 0.9)
    assert vehicle.mode is Mode.OFFBOARD
    run_s(vehicle, 0.2)  # past COM_OF_LOSS_T = 1 s
    assert vehicle.mode is Mode.AUTO_LOITER
    run_s(vehicle, 5.0)  # past COM_OBL_LAND_T = 5 s more
    assert vehicle.mode is Mode.AUTO_LAND


@pytest.mark.parametrize("gap_s", [2.0, 6.5])
def test_setpoints_back_after_a_loss_give_offboard_back_in_the_hold_and_in_the_land(vehicle: SimVehicle,
                                                                                   gap_s: float) -> None:
    """Real PX4 went back to OFFBOARD when the setpoints came back, after a failsafe of 5 s too
    (results/conformance/setpoint-gap.json); the stream it gets back is the one it flies."""
    vehicle.reset_episode(seed=2)
    vehicle.offboard_setpoint(body_velocity())
    vehicle.request_mode(Mode.OFFBOARD)
    run_s(vehicle, gap_s)  # simulation time: run_s steps the FDM, no wall clock
    land_after_s = vehicle.params.get("COM_OF_LOSS_T") + vehicle.params.get("COM_OBL_LAND_T")  # 1 + 5 s
    assert vehicle.mode is (Mode.AUTO_LOITER if gap_s < land_after_s else Mode.AUTO_LAND)
    run_s(vehicle, 0.5, lambda v: v.offboard_setpoint(body_velocity(forward=1.0)))
    assert vehicle.mode is Mode.OFFBOARD
    run_s(vehicle, 2.0, lambda v: v.offboard_setpoint(body_velocity(forward=1.0)))
    assert vehicle.state.velocity_ned_m_s[0] == pytest.approx(1.0, abs=0.15)


def test_a_mode_asked_for_in_the_failsafe_is_kept_when_setpoints_come_back(vehicle: SimVehicle) -> None:
    """The person took over (asked for a hold): the stream coming back does not take it away."""
    vehicle.reset_episode(seed=2)
    vehicle.offboard_setpoint(body_velocity())
    vehicle.request_mode(Mode.OFFBOARD)
    run_s(vehicle, 2.0)
    assert vehicle.request_mode(Mode.AUTO_LOITER)[0] == M.MAV_RESULT_ACCEPTED
    run_s(vehicle, 8.0, lambda v: v.offboard_setpoint(body_velocity(forward=1.0)))
    assert vehicle.mode is Mode.AUTO_LOITER  # neither OFFBOARD again nor the failsafe's land


def test_nan_setpoints_are_refused_and_do_not_keep_offboard_alive(vehicle: SimVehicle) -> None:
    vehicle.reset_episode(seed=3)
    vehicle.offboard_setpoint(body_velocity())
    vehicle.request_mode(Mode.OFFBOARD)
    bad = body_velocity(forward=math.nan)
    run_s(vehicle, 1.5, lambda v: v.offboard_setpoint(bad))  # past COM_OF_LOSS_T = 1 s
    assert vehicle.rejected_setpoints > 0
    assert vehicle.mode is Mode.AUTO_LOITER  # the stream of garbage counts as no stream
    assert all(math.isfinite(c) for c in vehicle.state.position_ned_m)


def test_reset_places_vehicle_above_pad_hovering_and_is_seeded(vehicle: SimVehicle) -> None:
    start = vehicle.reset_episode(seed=11)
    pad = vehicle.world.pad_ned(vehicle.time_s)
    assert start[2] - pad[2] == pytest.approx(-8.0)
    assert abs(start[0] - pad[0]) <= 3.0 and abs(start[1] - pad[1]) <= 3.0
    assert vehicle.armed and vehicle.mode is Mode.AUTO_LOITER and not vehicle.landed
    run_s(vehicle, 2.0)
    assert vehicle.state.position_ned_m[2] == pytest.approx(start[2], abs=0.1)
    again = SimVehicle(SitlConfig()).reset_episode(seed=11)
    assert tuple(again) == tuple(start)


def test_descending_onto_the_pad_is_a_successful_touchdown(vehicle: SimVehicle) -> None:
    vehicle.reset_episode(seed=4)
    pad = vehicle.world.pad_ned(vehicle.time_s)
    from sitl.offboard import FRAME_LOCAL_NED

    goto = TargetFields(FRAME_LOCAL_NED, 0b110111111000, pad[0], pad[1], pad[2] - 2.0, 0, 0, 0, 0, 0)
    vehicle.offboard_setpoint(goto)
    vehicle.request_mode(Mode.OFFBOARD)
    run_s(vehicle, 8.0, lambda v: v.offboard_setpoint(goto))
    down = TargetFields(FRAME_LOCAL_NED, 0b110111000011 & ~0b11, pad[0], pad[1], 0, 0, 0, 0.5, 0, 0)
    run_s(vehicle, 8.0, lambda v: v.offboard_setpoint(down))
    td = vehicle.touchdown
    assert td is not None and td.on_pad and td.success
    assert td.distance_to_pad_m < 0.3
    assert vehicle.landed
    assert vehicle.state.position_ned_m[2] == pytest.approx(-1.5, abs=0.2)  # on the roof


def test_manual_control_flies_in_posctl(vehicle: SimVehicle) -> None:
    vehicle.reset_episode(seed=5)
    assert vehicle.request_mode(Mode.POSCTL)[0] == M.MAV_RESULT_ACCEPTED
    e0 = vehicle.state.position_ned_m[1]
    run_s(vehicle, 3.0, lambda v: v.manual_control(0, 1000, 500, 0))  # full right
    assert vehicle.state.position_ned_m[1] - e0 > 3.0
    e1 = vehicle.state.position_ned_m[1]
    run_s(vehicle, 3.0, lambda v: v.manual_control(0, 0, 500, 0))  # centred: hold
    assert abs(vehicle.state.velocity_ned_m_s[1]) < 0.3
    assert vehicle.state.position_ned_m[1] - e1 < 3.0


def test_an_episode_does_not_depend_on_the_episodes_before_it() -> None:
    def fly(v: SimVehicle, seed: int) -> list[tuple[float, ...]]:
        v.reset_episode(seed)
        trace = []
        for i in range(600):
            if i % 12 == 0:
                v.offboard_setpoint(body_velocity(math.sin(i / 50), math.cos(i / 70), 0.3, 0.1))
                if i == 12:
                    v.request_mode(Mode.OFFBOARD)
            s = v.step()
            trace.append(s.position_ned_m + s.attitude_rad)
        return trace

    fresh = fly(SimVehicle(SitlConfig()), 5)
    used = SimVehicle(SitlConfig())
    fly(used, 7)
    assert fly(used, 5) == fresh  # bit for bit


def test_a_speed_limit_set_by_parameter_is_flown_at_once(vehicle: SimVehicle) -> None:
    vehicle.reset_episode(seed=6)
    assert vehicle.set_param("MPC_XY_VEL_MAX", 1.0)
    fast = body_velocity(forward=4.0)
    vehicle.offboard_setpoint(fast)
    vehicle.request_mode(Mode.OFFBOARD)
    run_s(vehicle, 4.0, lambda v: v.offboard_setpoint(fast))
    assert vehicle.state.velocity_ned_m_s[0] == pytest.approx(1.0, abs=0.1)
    assert vehicle.controller.cfg.max_speed_xy_m_s == 1.0
    assert not vehicle.set_param("NO_SUCH_PARAM", 1.0)


@pytest.mark.parametrize(("mode", "speed", "loss_t"), [("realtime", 1.0, 1.0), ("realtime", 4.0, 4.0),
                                                      ("realtime", 0.5, 0.5), ("lockstep", 4.0, 1.0)])
def test_the_offboard_loss_time_scales_with_the_speed_as_px4s_start_script_sets_it(mode: str, speed: float,
                                                                                    loss_t: float) -> None:
    """PX4's rcS: COM_OF_LOSS_T = speed factor x 1 s; real PX4 SIH at 2x read 2.0 and failed safe 2 s into a gap."""
    cfg = SitlConfig.model_validate({"clock": {"mode": mode, "speed": speed}})
    assert SimVehicle(cfg).params.get("COM_OF_LOSS_T") == pytest.approx(loss_t)
