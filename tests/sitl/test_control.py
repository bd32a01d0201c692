"""The flight-control cascade: mixer, thrust model, NaN safety, and closed-loop goals on JSBSim."""

from __future__ import annotations

import math

import pytest

from sitl.config import AutopilotConfig, WorldConfig
from sitl.control import (
    ESC_OFF,
    HOLD,
    MOTOR_PITCH,
    MOTOR_ROLL,
    MOTOR_YAW,
    FlightController,
    Setpoint,
    mix,
    throttle_for_lift,
)
from sitl.dynamics import Dynamics, VehicleState
from sitl.land_detector import LandDetector
from sitl.world import World

NAN = math.nan
CFG = AutopilotConfig()


# ---------------------------------------------------------------- mixer and thrust model


def torques(esc: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
    """Roll, pitch, yaw and collective implied by four motor commands (MOTOR_ORDER)."""
    fr, al, fl, ar = esc
    return (al + fl - fr - ar) / 4, (fr + fl - al - ar) / 4, (fr + al - fl - ar) / 4, sum(esc) / 4


@pytest.mark.parametrize(
    ("axis", "expected"),
    [
        ("roll", (-1, 1, 1, -1)),  # right wing down: left motors up
        ("pitch", (1, -1, 1, -1)),  # nose up: front motors up
        ("yaw", (1, 1, -1, -1)),  # nose right: counter-clockwise motors up
    ],
)
def test_each_axis_moves_the_motors_with_the_documented_signs(axis, expected) -> None:
    assert expected == {"roll": MOTOR_ROLL, "pitch": MOTOR_PITCH, "yaw": MOTOR_YAW}[axis]
    command = {"roll": 0.0, "pitch": 0.0, "yaw": 0.0, axis: 0.1}
    esc = mix(0.5, **command)
    for value, sign in zip(esc, expected, strict=True):
        assert value == pytest.approx(0.5 + 0.1 * sign)


def test_collective_alone_moves_all_motors_together() -> None:
    assert mix(0.3, 0.0, 0.0, 0.0) == pytest.approx((0.3, 0.3, 0.3, 0.3))


def test_saturation_keeps_roll_and_pitch_and_sacrifices_thrust_then_yaw() -> None:
    esc = mix(0.95, 0.2, 0.0, 0.3)
    assert all(0.0 <= e <= 1.0 for e in esc)
    roll, pitch, yaw, collective = torques(esc)
    assert roll == pytest.approx(0.2)  # attitude authority kept in full
    assert pitch == pytest.approx(0.0)
    assert collective < 0.95  # thrust gave way
    assert 0.0 <= yaw < 0.3  # yaw got only the room that was left


def test_roll_pitch_beyond_the_esc_range_is_scaled_keeping_direction() -> None:
    esc = mix(0.5, 0.6, 0.6, 0.0)
    assert all(0.0 <= e <= 1.0 for e in esc)
    roll, pitch, _, _ = torques(esc)
    assert roll == pytest.approx(pitch)
    assert roll > 0.2


def test_low_collective_is_raised_to_keep_attitude_authority() -> None:
    esc = mix(0.0, 0.1, 0.0, 0.0)
    assert min(esc) == pytest.approx(0.0)
    assert torques(esc)[0] == pytest.approx(0.1)


def test_mixer_outputs_stay_in_range_for_any_input(rng) -> None:
    for values in rng.uniform(-3, 3, size=(500, 4)):
        esc = mix(*values)
        assert all(0.0 <= e <= 1.0 for e in esc)


def test_thrust_model_hovers_at_hover_throttle_and_grows_with_lift() -> None:
    hover = CFG.hover_throttle
    assert throttle_for_lift(1.0, hover, CFG.thrust_curve_quadratic) == pytest.approx(hover)
    levels = [throttle_for_lift(r, hover, CFG.thrust_curve_quadratic) for r in (0.3, 1, 2, 3)]
    assert levels == sorted(levels)
    assert levels[-1] < 1.0


# ---------------------------------------------------------------- controller alone


def still_state(**overrides) -> VehicleState:
    fields = {
        "time_s": 0.0,
        "position_ned_m": (0.0, 0.0, -5.0),
        "velocity_ned_m_s": (0.0, 0.0, 0.0),
        "attitude_rad": (0.0, 0.0, 0.0),
        "rates_frd_rad_s": (0.0, 0.0, 0.0),
        "accel_frd_m_s2": (0.0, 0.0, -9.8),
        "on_ground": False,
    }
    fields.update(overrides)
    return VehicleState(**fields)


def test_disarmed_outputs_zero_and_forgets_integrators() -> None:
    fc = FlightController(CFG, 1 / 126)
    for _ in range(50):
        fc.update(still_state(), Setpoint(velocity_ned_m_s=(0.1, 0.0, 0.0)), True)
    assert fc.update(still_state(), HOLD, False) == ESC_OFF
    armed = fc.update(still_state(), HOLD, True)
    assert armed == pytest.approx((CFG.hover_throttle,) * 4, abs=1e-9)


@pytest.mark.parametrize(
    "sp",
    [
        Setpoint(),
        Setpoint(position_ned_m=(NAN, 1.0, NAN), velocity_ned_m_s=(NAN, NAN, 0.5)),
        Setpoint(position_ned_m=(math.inf, -math.inf, NAN), yaw_rad=NAN, yaw_rate_rad_s=NAN),
        Setpoint(velocity_ned_m_s=(math.inf, NAN, -math.inf), yaw_rate_rad_s=math.inf),
        Setpoint(position_ned_m=(NAN, NAN, NAN), yaw_rad=math.inf),
        Setpoint(position_ned_m=(1e300, -1e300, 1e300), velocity_ned_m_s=(1e300, 1e300, 1e300)),
    ],
)
def test_nan_and_inf_setpoints_never_make_nan_escs(sp: Setpoint) -> None:
    fc = FlightController(CFG, 1 / 126)
    for _ in range(20):
        esc = fc.update(still_state(), sp, True)
        assert all(math.isfinite(e) and 0.0 <= e <= 1.0 for e in esc)


def test_setpoint_rejects_wrong_shapes() -> None:
    with pytest.raises(ValueError, match="3 components"):
        Setpoint(position_ned_m=(1.0, 2.0))  # type: ignore[arg-type]


def test_speed_limits_bound_the_velocity_command() -> None:
    fc = FlightController(CFG, 1 / 126)
    far = Setpoint(position_ned_m=(1000.0, 1000.0, -1000.0))
    vn, ve, vd = fc._velocity_command(still_state(), far)
    assert math.hypot(vn, ve) == pytest.approx(CFG.max_speed_xy_m_s)
    assert vd == pytest.approx(-CFG.max_speed_up_m_s)
    down = Setpoint(velocity_ned_m_s=(0.0, 0.0, 50.0))
    assert fc._velocity_command(still_state(), down)[2] == pytest.approx(CFG.max_speed_down_m_s)


def test_land_detector_needs_contact_stillness_and_low_thrust_for_a_while() -> None:
    dt = 1 / 126
    ld = LandDetector(dt, hold_s=0.3)
    ground = still_state(on_ground=True)
    assert not any(ld.update(ground, 1.0) for _ in range(100))  # pushing up: not landed
    assert not any(ld.update(still_state(), 0.5) for _ in range(100))  # flying
    moving = still_state(on_ground=True, velocity_ned_m_s=(1.0, 0.0, 0.0))
    assert not any(ld.update(moving, 0.5) for _ in range(100))
    results = [ld.update(ground, 0.5) for _ in range(60)]
    assert not results[round(0.25 / dt)]
    assert results[-1]


# ---------------------------------------------------------------- closed loop on JSBSim


@pytest.fixture(scope="module")
def world() -> World:
    return World(WorldConfig())


@pytest.fixture(scope="module")
def sim(world: World) -> tuple[Dynamics, FlightController]:
    dyn = Dynamics(surface_height_m=world.surface_height_m)
    return dyn, FlightController(CFG, dyn.dt_s)


def start(sim, position=(6.0, 6.0, -10.0), yaw_rad: float = 0.0) -> VehicleState:
    dyn, fc = sim
    fc.reset()
    return dyn.reset(position, yaw_rad=yaw_rad, time_s=0.0)


def fly(sim, sp: Setpoint, seconds: float, armed: bool = True) -> list[VehicleState]:
    dyn, fc = sim
    state, out = dyn.state, []
    for _ in range(round(seconds / dyn.dt_s)):
        state = dyn.step(fc.update(state, sp, armed))
        out.append(state)
    return out


def body_forward_m_s(s: VehicleState) -> float:
    yaw = s.attitude_rad[2]
    return math.cos(yaw) * s.velocity_ned_m_s[0] + math.sin(yaw) * s.velocity_ned_m_s[1]


@pytest.mark.parametrize("yaw_rad", [0.0, 1.0, -2.5])
def test_body_velocity_step_settles_fast_without_ringing(sim, yaw_rad: float) -> None:
    start(sim, yaw_rad=yaw_rad)
    fly(sim, Setpoint(velocity_ned_m_s=(0.0, 0.0, 0.0), yaw_rad=yaw_rad), 0.5)
    step = Setpoint(velocity_ned_m_s=(math.cos(yaw_rad), math.sin(yaw_rad), 0.0), yaw_rad=yaw_rad)
    states = fly(sim, step, 4.0)
    forward = [body_forward_m_s(s) for s in states]
    dt = sim[0].dt_s
    outside = [i for i, v in enumerate(forward) if abs(v - 1.0) > 0.1]
    settle_s = (outside[-1] + 1) * dt if outside else 0.0
    assert settle_s < 1.5
    assert max(forward) < 1.08  # small overshoot
    tail = forward[round(2.0 / dt) :]
    assert max(tail) - min(tail) < 0.03  # no sustained ringing
    assert abs(tail[-1] - 1.0) < 0.02


def test_hover_holds_altitude_within_a_decimetre(sim) -> None:
    start(sim, position=(6.0, 6.0, -8.0))
    states = fly(sim, Setpoint(position_ned_m=(6.0, 6.0, -8.0)), 10.0)
    assert max(abs(s.position_ned_m[2] + 8.0) for s in states) < 0.1


def test_velocity_hold_keeps_altitude_while_moving(sim) -> None:
    start(sim)
    states = fly(sim, Setpoint(velocity_ned_m_s=(3.0, -2.0, 0.0)), 5.0)
    assert max(abs(s.position_ned_m[2] + 10.0) for s in states) < 0.1
    assert states[-1].velocity_ned_m_s == pytest.approx((3.0, -2.0, 0.0), abs=0.05)


def test_yaw_rate_is_tracked(sim) -> None:
    start(sim)
    states = fly(sim, Setpoint(velocity_ned_m_s=(0.0, 0.0, 0.0), yaw_rate_rad_s=1.0), 4.0)
    rates = [s.rates_frd_rad_s[2] for s in states[round(1.0 / sim[0].dt_s) :]]
    assert sum(rates) / len(rates) == pytest.approx(1.0, abs=0.05)
    assert max(rates) < 1.1


def test_yaw_rate_is_limited(sim) -> None:
    start(sim)
    states = fly(sim, Setpoint(yaw_rate_rad_s=10.0), 2.0)
    assert states[-1].rates_frd_rad_s[2] == pytest.approx(CFG.max_yaw_rate_rad_s, abs=0.1)


def test_position_and_heading_hold_converge(sim) -> None:
    start(sim)
    target = (9.0, 4.0, -7.0)
    states = fly(sim, Setpoint(position_ned_m=target, yaw_rad=3.0), 10.0)
    assert states[-1].position_ned_m == pytest.approx(target, abs=0.05)
    assert states[-1].attitude_rad[2] == pytest.approx(3.0, abs=0.02)
    tilts = [max(abs(s.attitude_rad[0]), abs(s.attitude_rad[1])) for s in states]
    assert max(tilts) <= CFG.max_tilt_rad + 0.05


def test_no_setpoint_axis_holds_velocity_zero(sim) -> None:
    start(sim)
    fly(sim, Setpoint(velocity_ned_m_s=(2.0, 0.0, 0.0)), 2.0)
    states = fly(sim, HOLD, 3.0)
    assert states[-1].velocity_ned_m_s == pytest.approx((0.0, 0.0, 0.0), abs=0.05)


def descend(sim, north_m: float, east_m: float, seconds: float) -> tuple[list, LandDetector]:
    """Descend at land speed above (north, east); disarm once the land detector says so."""
    dyn, fc = sim
    detector = LandDetector(dyn.dt_s)
    sp = Setpoint(
        position_ned_m=(north_m, east_m, NAN), velocity_ned_m_s=(0, 0, CFG.land_speed_m_s)
    )
    state, armed, out = dyn.state, True, []
    for _ in range(round(seconds / dyn.dt_s)):
        state = dyn.step(fc.update(state, sp, armed))
        if armed and detector.update(state, fc.lift_ratio):
            armed = False
        out.append(state)
    return out, detector


def test_descending_over_the_roof_lands_on_it_and_stays(sim, world: World) -> None:
    start(sim, position=(0.4, -0.3, -6.0))
    states, detector = descend(sim, 0.4, -0.3, 12.0)
    assert detector.landed
    final = states[-1]
    assert final.on_ground
    assert final.position_ned_m == pytest.approx((0.4, -0.3, -world.roof_height_m), abs=0.05)
    touchdown = sim[0].last_contact
    assert touchdown is not None
    assert touchdown.speed_m_s == pytest.approx(CFG.land_speed_m_s, abs=0.1)
    assert world.judge(touchdown.position_ned_m, touchdown.speed_m_s, final.time_s).success
    # landed early in the run, then sat still and disarmed on the roof
    landed_at = next(i for i, s in enumerate(states) if s.on_ground)
    assert all(s.position_ned_m[2] < -1.4 for s in states[landed_at:])


def test_descending_beside_the_vehicle_lands_on_the_ground(sim, world: World) -> None:
    start(sim, position=(4.5, 0.0, -5.0))
    states, detector = descend(sim, 4.5, 0.0, 12.0)
    assert detector.landed
    assert states[-1].position_ned_m == pytest.approx((4.5, 0.0, 0.0), abs=0.05)
    touchdown = sim[0].last_contact
    assert touchdown is not None
    assert not world.judge(touchdown.position_ned_m, touchdown.speed_m_s, 0.0).on_pad


def test_land_detector_stays_quiet_in_flight(sim) -> None:
    dyn, fc = sim
    start(sim)
    detector = LandDetector(dyn.dt_s)
    state = dyn.state
    for _ in range(round(3.0 / dyn.dt_s)):
        state = dyn.step(fc.update(state, Setpoint(velocity_ned_m_s=(1.0, 0.0, 0.5)), True))
        assert not detector.update(state, fc.lift_ratio)


def test_takes_off_from_the_ground(sim) -> None:
    start(sim, position=(6.0, 6.0, 0.0))
    states = fly(sim, Setpoint(position_ned_m=(6.0, 6.0, -2.5)), 6.0)
    assert states[-1].position_ned_m == pytest.approx((6.0, 6.0, -2.5), abs=0.05)
    assert not states[-1].on_ground


def test_climb_to_descent_reversal_respects_the_descent_limit(sim) -> None:
    start(sim, position=(6.0, 6.0, -30.0))
    fly(sim, Setpoint(velocity_ned_m_s=(3.0, 3.0, -3.0)), 3.0)
    states = fly(sim, Setpoint(velocity_ned_m_s=(0.0, 0.0, 10.0)), 4.0)
    assert max(s.velocity_ned_m_s[2] for s in states) < CFG.max_speed_down_m_s + 0.1
    assert states[-1].velocity_ned_m_s[2] == pytest.approx(CFG.max_speed_down_m_s, abs=0.05)


def test_a_wrong_hover_throttle_is_learnt_by_the_integrator() -> None:
    cfg = CFG.model_copy(update={"hover_throttle": 0.38})
    dyn = Dynamics()
    fc = FlightController(cfg, dyn.dt_s)
    state = dyn.reset((0.0, 0.0, -10.0))
    hold = Setpoint(position_ned_m=(0.0, 0.0, -10.0))
    for _ in range(round(10.0 / dyn.dt_s)):
        state = dyn.step(fc.update(state, hold, True))
    assert state.position_ned_m[2] == pytest.approx(-10.0, abs=0.02)
