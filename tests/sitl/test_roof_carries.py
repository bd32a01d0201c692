"""The driving roof carries the multirotor ([sitl.world] roof_carries): standing on it, touching
down on it while matching its velocity, flying across its edge, and the key off as before."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sitl.config import AutopilotConfig, SitlConfig, WorldConfig
from sitl.control import FlightController, Setpoint
from sitl.dynamics import _TOP_XML, Atmosphere, Dynamics, VehicleState, _top_xml
from sitl.modes import Mode
from sitl.offboard import FRAME_LOCAL_NED, TargetFields
from sitl.vehicle import SimVehicle
from sitl.world import World

OFF = (0.0, 0.0, 0.0, 0.0)
CFG = AutopilotConfig()
TURNING = {"vehicle_turn_rate_rad_s": 0.3, "vehicle_speed_change": 0.5, "vehicle_speed_change_period_s": 6.0}


def world_and_dynamics(velocity_ne: tuple[float, float], carries: bool, **motion: float) -> tuple[World, Dynamics]:
    world = World(WorldConfig(vehicle_velocity_ne_m_s=velocity_ne, roof_carries=carries, **motion))
    world.restart(0.0)
    dyn = Dynamics(surface_height_m=world.surface_height_m, max_surface_height_m=world.roof_height_m,
                   carrier=world, carries=carries)
    return world, dyn


def off_pad_ne(world: World, s: VehicleState) -> np.ndarray:
    return np.subtract(s.position_ned_m[:2], world.pad_ned(s.time_s)[:2])


def stand(dyn: Dynamics, seconds: float) -> list[VehicleState]:
    return [dyn.step(OFF) for _ in range(round(seconds / dyn.dt_s))]


@pytest.mark.parametrize("motion", [{}, TURNING], ids=["straight", "turning"])
def test_a_vehicle_standing_on_the_driving_roof_is_carried(motion: dict) -> None:
    world, dyn = world_and_dynamics((1.5, 0.0), carries=True, **motion)
    start = dyn.reset((0.3, 0.2, 0.0), time_s=0.0)  # below the roof: set on it, at rest on it
    assert start.on_ground and start.velocity_ned_m_s == pytest.approx((1.5, 0.0, 0.0))
    states = stand(dyn, 5.0)
    for s in states[::20]:
        assert s.on_ground and s.position_ned_m[2] == pytest.approx(-world.roof_height_m, abs=0.01)
        assert off_pad_ne(world, s) == pytest.approx((0.3, 0.2), abs=0.01)  # the same spot of the roof
        assert s.velocity_ned_m_s[:2] == pytest.approx(world.velocity_at(s.time_s), abs=0.02)
        assert max(abs(s.attitude_rad[0]), abs(s.attitude_rad[1])) < 0.01
    if motion:  # the IMU feels the roof's acceleration: the turn's centripetal and the speed change
        accel = [math.hypot(*s.accel_frd_m_s2[:2]) for s in states]
        assert max(accel) > 0.4


def test_without_roof_carries_the_roof_slides_away_under_it() -> None:
    world, dyn = world_and_dynamics((1.5, 0.0), carries=False)
    dyn.reset((0.3, 0.2, 0.0), time_s=0.0)
    final = stand(dyn, 5.0)[-1]
    assert final.velocity_ned_m_s == pytest.approx((0.0, 0.0, 0.0), abs=0.01)  # still in the world
    assert final.position_ned_m[2] == pytest.approx(0.0, abs=0.01)  # fell off onto the ground
    assert not world.over_roof(final.position_ned_m[0], final.position_ned_m[1], final.time_s)


def descend_matching(world: World, dyn: Dynamics, velocity_ne: tuple[float, float], seconds: float) -> list[VehicleState]:
    """From 3 m above the pad, descend at land speed with the roof's velocity; motors off at contact."""
    fc = FlightController(CFG, dyn.dt_s)
    s = dyn.reset((0.0, 0.0, -4.5), velocity_ned_m_s=(*velocity_ne, 0.0), time_s=0.0)
    sp = Setpoint(velocity_ned_m_s=(*velocity_ne, CFG.land_speed_m_s))
    armed, out = True, []
    for _ in range(round(seconds / dyn.dt_s)):
        s = dyn.step(fc.update(s, sp, armed))
        armed = armed and not s.on_ground
        out.append(s)
    return out


@pytest.mark.parametrize("speed_m_s", [1.0, 1.5])
def test_a_descent_matching_the_roof_touches_down_softly_on_the_pad(speed_m_s: float) -> None:
    velocity_ne = (0.6 * speed_m_s, 0.8 * speed_m_s)
    world, dyn = world_and_dynamics(velocity_ne, carries=True)
    states = descend_matching(world, dyn, velocity_ne, 7.0)
    contact = dyn.last_contact
    assert contact is not None
    assert contact.surface_velocity_ned_m_s == pytest.approx((*velocity_ne, 0.0))
    assert math.hypot(*contact.relative_velocity_ned_m_s[:2]) < 0.05  # matched: no slide
    assert contact.relative_velocity_ned_m_s[2] == pytest.approx(CFG.land_speed_m_s, abs=0.05)
    assert contact.speed_m_s > speed_m_s  # in the world it was fast
    assert world.judge(np.asarray(contact.position_ned_m), contact.relative_speed_m_s, contact.time_s).success
    landed = [s for s in states if s.time_s >= contact.time_s]
    assert max(max(abs(s.attitude_rad[0]), abs(s.attitude_rad[1])) for s in landed) < 0.05  # no tipping
    assert np.hypot(*off_pad_ne(world, states[-1])) < 0.05 and states[-1].on_ground  # carried on the pad


def test_without_roof_carries_the_same_touchdown_is_braked_as_on_still_ground() -> None:
    velocity_ne = (0.6, 0.8)
    world, dyn = world_and_dynamics(velocity_ne, carries=False)
    states = descend_matching(world, dyn, velocity_ne, 7.0)
    tilt = max(max(abs(s.attitude_rad[0]), abs(s.attitude_rad[1])) for s in states)
    assert tilt > 0.1 or np.hypot(*off_pad_ne(world, states[-1])) > 0.5


def fly_across_the_roof(carries: bool, atmosphere: Atmosphere | None, motion: dict) -> tuple[list[VehicleState], int]:
    """Low over the driving roof and off it again (the frame switches twice with the key on)."""
    world, dyn = world_and_dynamics((1.5, 0.0), carries=carries, **motion)
    dyn.set_atmosphere(atmosphere)
    fc = FlightController(CFG, dyn.dt_s)
    s = dyn.reset((0.0, 2.0, -2.2), velocity_ned_m_s=(1.4, -1.2, 0.0), time_s=0.0)
    sp = Setpoint(velocity_ned_m_s=(1.4, -1.2, 0.0))
    states, switches, on_roof = [], 0, False
    for _ in range(round(5.0 / dyn.dt_s)):
        s = dyn.step(fc.update(s, sp, True))
        states.append(s)
        roof_frame = dyn.carried_velocity_ne_m_s != (0.0, 0.0)
        switches += roof_frame != on_roof
        on_roof = roof_frame
    return states, switches


@pytest.mark.parametrize(("atmosphere", "motion", "position_m"),
                         [(None, {}, 0.001), (Atmosphere((3.0, -2.0)), {}, 0.001), (None, TURNING, 0.01)],
                         ids=["calm", "wind", "turning"])
def test_a_flight_across_the_roof_is_the_same_in_either_frame(atmosphere: Atmosphere | None, motion: dict,
                                                               position_m: float) -> None:
    """In flight the frame is invisible: the frame force, the wind relative to the frame and the
    IMU's correction give the world's flight, through both switches of the frame. (In a turning
    roof's frame the positions part by millimetres: the frame's offset is the roof's exact path,
    JSBSim integrates the relative velocity a step late; see sitl/roof_frame.py.)"""
    carried, switches = fly_across_the_roof(True, atmosphere, motion)
    still, _ = fly_across_the_roof(False, atmosphere, motion)
    assert switches == 2
    for a, b in zip(carried, still, strict=True):
        assert a.position_ned_m == pytest.approx(b.position_ned_m, abs=position_m)
        assert a.velocity_ned_m_s == pytest.approx(b.velocity_ned_m_s, abs=1e-3)
        assert a.accel_frd_m_s2 == pytest.approx(b.accel_frd_m_s2, abs=1e-3)
        assert a.attitude_rad == pytest.approx(b.attitude_rad, abs=1e-4)


def test_a_sudden_stop_of_the_roof_slides_the_vehicle_along_it() -> None:
    world, dyn = world_and_dynamics((1.5, 0.0), carries=True)
    dyn.reset((0.0, 0.0, 0.0), time_s=0.0)
    before = stand(dyn, 1.0)[-1]
    world.set_velocity((0.0, 0.0), before.time_s)  # set_ground_vehicle: the roof stops at once
    after = stand(dyn, 2.0)
    assert after[0].velocity_ned_m_s[0] == pytest.approx(1.5, abs=0.05)  # its world velocity is kept
    assert after[-1].velocity_ned_m_s == pytest.approx((0.0, 0.0, 0.0), abs=0.01)  # friction stops it on the roof
    assert 0.1 < off_pad_ne(world, after[-1])[0] < 0.4 and after[-1].on_ground


def test_with_the_key_off_a_step_is_the_one_without_a_carrier() -> None:
    """Off, the dynamics are those before the key, float for float: the same model file, the same
    states, through a touchdown on the driving roof and a fall off it."""
    assert _top_xml(False) is _TOP_XML
    runs = []
    for with_carrier in (False, True):
        world = World(WorldConfig(vehicle_velocity_ne_m_s=(0.6, 0.8)))
        world.restart(0.0)
        if with_carrier:
            dyn = Dynamics(surface_height_m=world.surface_height_m, max_surface_height_m=world.roof_height_m,
                           carrier=world, carries=False)
        else:
            dyn = Dynamics(surface_height_m=world.surface_height_m, max_surface_height_m=world.roof_height_m)
        runs.append((descend_matching(world, dyn, (0.6, 0.8), 6.0), dyn.wind_ned_m_s(), dyn.last_contact))
    (without, wind_a, contact_a), (with_, wind_b, contact_b) = runs
    assert without == with_ and wind_a == wind_b
    assert contact_a is not None and contact_b is not None
    assert (contact_a.time_s, contact_a.position_ned_m, contact_a.velocity_ned_m_s) == (
        contact_b.time_s, contact_b.position_ned_m, contact_b.velocity_ned_m_s)


def sim_vehicle(carries: bool, speed_m_s: float) -> SimVehicle:
    base = SitlConfig()
    world = base.world.model_copy(update={"vehicle_velocity_ne_m_s": (speed_m_s, 0.0), "start_xy_range_m": 0.0,
                                          "start_height_above_pad_m": 3.0, "roof_carries": carries})
    autopilot = base.autopilot.model_copy(update={"land_detector": "contact"})
    return SimVehicle(base.model_copy(update={"world": world, "autopilot": autopilot}))


def test_the_vehicle_judges_a_touchdown_on_the_carrying_roof_relative_to_it() -> None:
    """Offboard, descending with the roof's velocity: it settles on the roof at the roof's speed,
    touches down on the pad at the land speed relative to it, lands and disarms there."""
    v = sim_vehicle(True, 1.5)
    v.reset_episode(seed=1)
    follow = TargetFields(FRAME_LOCAL_NED, 0x5C7, 0, 0, 0, 1.5, 0.0, 0.7, 0, 0)
    v.offboard_setpoint(follow)
    v.request_mode(Mode.OFFBOARD)
    for i in range(round(8.0 / v.dynamics.dt_s)):  # touchdown at 4.3 s, disarmed 2 s later (COM_DISARM_LAND)
        if i % 12 == 0:
            v.offboard_setpoint(follow)
        v.step()
    td = v.touchdown
    assert td is not None and td.success
    assert td.speed_m_s == pytest.approx(0.7, abs=0.05)  # relative to the roof, not 1.66 m/s in the world
    assert v.landed and not v.armed
    assert v.state.velocity_ned_m_s == pytest.approx((1.5, 0.0, 0.0), abs=0.02)  # carried


def test_a_vehicle_booted_beside_the_driving_roof_stands_still() -> None:
    """The open ground is the ground's frame: with the key on, a vehicle standing on it stays put."""
    v = sim_vehicle(True, 1.5)
    start = v.state.position_ned_m
    for _ in range(round(2.0 / v.dynamics.dt_s)):
        v.step()
    assert v.state.position_ned_m == pytest.approx(start, abs=1e-3)
    assert v.state.velocity_ned_m_s == pytest.approx((0.0, 0.0, 0.0), abs=1e-3)
