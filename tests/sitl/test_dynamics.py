"""The JSBSim F450 wrapper: poses, motors, surfaces, contacts, quietness."""

from __future__ import annotations

import math

import pytest

from companion.errors import ConfigError, SimulatorError
from sitl.config import WorldConfig
from sitl.dynamics import (
    GRAVITY_M_S2,
    HOVER_THROTTLE,
    Dynamics,
    geodetic_to_ned,
    ned_to_geodetic,
)
from sitl.world import World

OFF = (0.0, 0.0, 0.0, 0.0)
HOVER = (HOVER_THROTTLE,) * 4


@pytest.fixture(scope="module")
def dyn() -> Dynamics:
    return Dynamics()


@pytest.fixture(scope="module")
def world_dyn() -> tuple[World, Dynamics]:
    world = World(WorldConfig())
    return world, Dynamics(surface_height_m=world.surface_height_m)


def fly(dyn: Dynamics, esc: tuple[float, float, float, float], seconds: float):
    state = dyn.state
    for _ in range(round(seconds / dyn.dt_s)):
        state = dyn.step(esc)
    return state


def test_reset_in_the_air_places_the_vehicle_level_and_still(dyn: Dynamics) -> None:
    s = dyn.reset((12.0, -7.0, -20.0), yaw_rad=-2.5, time_s=3.0)
    assert s.time_s == 3.0
    assert s.position_ned_m == pytest.approx((12.0, -7.0, -20.0), abs=0.01)
    assert s.velocity_ned_m_s == pytest.approx((0, 0, 0), abs=1e-6)
    assert s.attitude_rad == pytest.approx((0.0, 0.0, -2.5), abs=1e-6)
    assert not s.on_ground


def test_reset_with_velocity_and_time_keeps_counting(dyn: Dynamics) -> None:
    dyn.reset((0.0, 0.0, -30.0), velocity_ned_m_s=(2.0, -1.0, 0.5), time_s=10.0)
    s = dyn.step(HOVER)
    assert s.velocity_ned_m_s[:2] == pytest.approx((2.0, -1.0), abs=0.05)
    fly(dyn, HOVER, 11 * dyn.dt_s)
    assert dyn.state.time_s == pytest.approx(10.0 + 12 * dyn.dt_s)
    assert dyn.reset((0.0, 0.0, -5.0)).time_s == pytest.approx(10.0 + 12 * dyn.dt_s)


def test_propellers_turn_at_hover_speed_after_an_air_reset(dyn: Dynamics) -> None:
    dyn.reset((0.0, 0.0, -10.0))
    s = fly(dyn, HOVER, 1.0)
    assert abs(s.velocity_ned_m_s[2]) < 0.15
    assert s.accel_frd_m_s2[2] == pytest.approx(-GRAVITY_M_S2, abs=0.5)


def test_free_fall_reads_no_specific_force(dyn: Dynamics) -> None:
    dyn.reset((0.0, 0.0, -50.0))
    s = fly(dyn, OFF, 0.8)  # propellers spun down, still falling slowly
    assert s.velocity_ned_m_s[2] > 5.0
    assert abs(s.accel_frd_m_s2[2]) < 1.0


def test_reset_on_the_ground_rests_there(dyn: Dynamics) -> None:
    s = dyn.reset((1.0, 2.0, 0.0))
    s = fly(dyn, OFF, 1.0)
    assert s.on_ground
    assert s.position_ned_m == pytest.approx((1.0, 2.0, 0.0), abs=0.02)
    assert s.accel_frd_m_s2[2] == pytest.approx(-GRAVITY_M_S2, abs=0.3)
    assert dyn.last_contact is None  # standing is not a touchdown


def test_a_position_below_ground_is_lifted_onto_it(dyn: Dynamics) -> None:
    s = dyn.reset((0.0, 0.0, 3.0))
    assert s.position_ned_m[2] == pytest.approx(0.0, abs=0.01)


@pytest.mark.parametrize(
    ("motor", "signs"),
    [
        (0, (-1, 1, 1)),  # front right: roll left, nose up, yaw right (spins CCW)
        (1, (1, -1, 1)),  # aft left: roll right, nose down, yaw right (CCW)
        (2, (1, 1, -1)),  # front left: roll right, nose up, yaw left (CW)
        (3, (-1, -1, -1)),  # aft right: roll left, nose down, yaw left (CW)
    ],
)
def test_each_motor_turns_the_vehicle_as_documented(
    dyn: Dynamics, motor: int, signs: tuple[int, int, int]
) -> None:
    dyn.reset((0.0, 0.0, -20.0))
    esc = [HOVER_THROTTLE] * 4
    esc[motor] += 0.05
    s = fly(dyn, tuple(esc), 0.1)
    for rate, sign in zip(s.rates_frd_rad_s, signs, strict=True):
        assert rate * sign > 0.05


def test_bad_esc_commands_never_reach_jsbsim(dyn: Dynamics) -> None:
    dyn.reset((0.0, 0.0, -20.0))
    s = fly(dyn, (math.nan, 5.0, -3.0, math.inf), 0.2)
    values = (*s.position_ned_m, *s.velocity_ned_m_s, *s.attitude_rad, *s.rates_frd_rad_s)
    assert all(math.isfinite(v) for v in values)
    # motor 0 off and motor 2 off, 1 and 3 full: the aft left/front right diagonal is
    # unbalanced, so the vehicle rolls and pitches but stays a number
    assert s.rates_frd_rad_s[0] != 0.0


def test_invalid_arguments_say_what_to_do(dyn: Dynamics) -> None:
    with pytest.raises(ConfigError, match="between 60 and 1000"):
        Dynamics(fdm_rate_hz=10.0)
    with pytest.raises(SimulatorError, match="finite"):
        dyn.reset((0.0, math.nan, -1.0))


def test_construction_and_reset_are_quiet(capfd: pytest.CaptureFixture[str]) -> None:
    d = Dynamics()
    d.reset((0.0, 0.0, -3.0))
    d.step(HOVER)
    out, err = capfd.readouterr()
    assert out == ""
    assert err == ""


def test_geodetic_conversion_round_trips_and_matches_jsbsim(dyn: Dynamics) -> None:
    lat, lon, alt = ned_to_geodetic(250.0, -120.0, -30.0)
    assert alt == pytest.approx(dyn.home_alt_m + 30.0)
    assert geodetic_to_ned(lat, lon, alt) == pytest.approx((250.0, -120.0, -30.0), abs=1e-6)
    # JSBSim's own geodesy agrees with the local frame to a centimetre
    s = dyn.reset((250.0, -120.0, -30.0))
    assert s.position_ned_m == pytest.approx((250.0, -120.0, -30.0), abs=0.01)


def test_a_falling_vehicle_lands_on_the_roof_and_stays(world_dyn) -> None:
    world, d = world_dyn
    d.reset((0.5, 0.3, -4.0), time_s=0.0)
    s = fly(d, OFF, 3.0)
    assert s.on_ground
    assert s.position_ned_m[2] == pytest.approx(-world.roof_height_m, abs=0.05)
    contact = d.last_contact
    assert contact is not None
    assert contact.position_ned_m[2] == pytest.approx(-world.roof_height_m, abs=0.05)
    assert contact.speed_m_s > 2.0


def test_off_the_roof_the_vehicle_lands_on_the_ground(world_dyn) -> None:
    world, d = world_dyn
    d.reset((4.0, 0.0, -3.0), time_s=0.0)
    s = fly(d, OFF, 3.0)
    assert s.on_ground
    assert s.position_ned_m[2] == pytest.approx(0.0, abs=0.05)


def test_a_reset_onto_the_roof_stands_on_it(world_dyn) -> None:
    world, d = world_dyn
    s = d.reset((0.0, 0.0, 0.0), time_s=0.0)
    assert s.position_ned_m[2] == pytest.approx(-world.roof_height_m, abs=0.01)
    s = fly(d, OFF, 1.0)
    assert s.on_ground
    assert s.position_ned_m[2] == pytest.approx(-world.roof_height_m, abs=0.02)


def test_the_side_of_the_ground_vehicle_is_not_a_floor(world_dyn) -> None:
    """Flying in low beside the vehicle and over its footprint must not launch it upward."""
    world, d = world_dyn
    d.reset((3.0, 0.0, -0.5), velocity_ned_m_s=(-3.0, 0.0, 0.0), time_s=0.0)
    s = fly(d, HOVER, 0.6)
    assert world.over_roof(s.position_ned_m[0], s.position_ned_m[1], s.time_s)
    assert s.velocity_ned_m_s[2] > -0.5  # no jump from a roof appearing under the legs


def test_a_hard_tilted_touchdown_stays_on_the_ground(dyn: Dynamics) -> None:
    """The contact model is stable: a bad landing may tip the vehicle, never launch it."""
    dyn.reset((0.0, 0.0, -0.3), velocity_ned_m_s=(3.0, 2.0, 4.0))
    highest_m = 0.0
    for _ in range(round(3.0 / dyn.dt_s)):
        s = dyn.step(OFF)
        highest_m = max(highest_m, -s.position_ned_m[2])
    assert highest_m < 1.0
    assert s.on_ground
    assert abs(s.position_ned_m[2]) < 0.3
    assert math.sqrt(sum(v * v for v in s.velocity_ned_m_s)) < 0.1


def test_max_surface_height_skips_lookups_high_up() -> None:
    calls: list[float] = []

    def surface(n: float, e: float, t: float) -> float:
        calls.append(t)
        return 0.0

    d = Dynamics(surface_height_m=surface, max_surface_height_m=1.5)
    d.reset((0.0, 0.0, -10.0))
    calls.clear()
    fly(d, HOVER, 0.5)
    assert calls == []
    d.reset((0.0, 0.0, -2.0))
    calls.clear()
    fly(d, HOVER, 0.5)
    assert len(calls) == round(0.5 / d.dt_s)


def test_a_roof_driving_under_a_hovering_vehicle_becomes_its_floor() -> None:
    world = World(WorldConfig(vehicle_velocity_ne_m_s=(2.0, 0.0)))
    d = Dynamics(surface_height_m=world.surface_height_m)
    d.reset((3.0, 0.0, -1.7), time_s=0.0)
    s = fly(d, HOVER, 1.0)  # the roof (north edge at 2 + 2 t) passes under the vehicle
    assert world.over_roof(s.position_ned_m[0], s.position_ned_m[1], s.time_s)
    s = fly(d, OFF, 0.6)
    assert s.on_ground
    assert s.position_ned_m[2] == pytest.approx(-world.roof_height_m, abs=0.05)
