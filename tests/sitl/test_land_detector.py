"""PX4's land detector (``autopilot.land_detector = "px4"``) against the old contact rule.

Real PX4 (main 2026-03, SIH): told to descend at 0.263 m/s it sat on the ground armed and never
landed; at 0.368 m/s it landed; AUTO.LAND landed. The detector alone is fed a made-up clock;
the vehicle tests fly JSBSim in process (no sockets).
"""

from __future__ import annotations

import math

import pytest
from pymavlink.dialects.v20 import common as M

from sitl.config import AutopilotConfig, SitlConfig
from sitl.dynamics import VehicleState
from sitl.handler import MessageHandler
from sitl.land_detector import Px4LandDetector
from sitl.modes import Mode
from sitl.offboard import FRAME_LOCAL_NED, TargetFields
from sitl.params import encode_value
from sitl.personality import make_vehicle
from sitl.telemetry import TelemetryScheduler, extended_sys_state
from sitl.vehicle import SimVehicle

DT = 1 / 126
VELOCITY_ONLY = 0b110111000111  # vx, vy, vz used; position, acceleration, yaw, yaw rate ignored
CONTACT = SitlConfig.model_validate({"autopilot": {"land_detector": "contact"}})


def ground_state(t_s: float, velocity=(0.0, 0.0, 0.0), rates=(0.0, 0.0, 0.0)) -> VehicleState:
    return VehicleState(t_s, (0.0, 0.0, 0.0), velocity, (0.0, 0.0, 0.0), rates, (0.0, 0.0, -9.81), True)


def feed(ld: Px4LandDetector, seconds: float, descent: float, lift: float = 0.85, t0: float = 0.0, **state) -> float | None:
    """Step the detector for ``seconds`` from ``t0``; the time it first said landed, or None."""
    for i in range(round(seconds / DT)):
        t = t0 + i * DT
        if ld.update(ground_state(t, **state), descent, lift, armed=True):
            return t - t0
    return None


def flying() -> Px4LandDetector:
    ld = Px4LandDetector(AutopilotConfig())
    ld.reset(landed=False)
    return ld


# ---------------------------------------------------------------- the detector alone


def test_a_commanded_descent_below_1_1_z_vel_max_never_lands() -> None:
    ld = flying()
    assert feed(ld, 20.0, descent=0.26) is None  # 0.26 < 1.1 x 0.25
    assert not ld.ground_contact and not ld.landed
    assert feed(ld, 20.0, descent=math.nan) is None  # a position setpoint alone: no descent


def test_a_commanded_descent_above_it_lands_after_the_trigger_time_in_three_stages() -> None:
    ld = flying()
    stages = []
    for i in range(round(2.0 / DT)):
        ld.update(ground_state(i * DT), 0.30, 0.85, armed=True)
        stages.append((ld.ground_contact, ld.maybe_landed, ld.landed))
    first = [next(i for i, s in enumerate(stages) if s[k]) * DT for k in range(3)]
    assert first[0] == pytest.approx(1 / 3, abs=0.02)
    assert first[1] == pytest.approx(2 / 3, abs=0.03)
    assert first[2] == pytest.approx(1.0, abs=0.05)  # LNDMC_TRIG_TIME in total


@pytest.mark.parametrize(
    ("what", "state", "lift"),
    [
        ("sliding", {"velocity": (1.6, 0.0, 0.0)}, 0.85),  # > LNDMC_XY_VEL_MAX
        ("sinking", {"velocity": (0.0, 0.0, 0.3)}, 0.85),  # > LNDMC_Z_VEL_MAX
        ("rolling", {"rates": (math.radians(25.0), 0.0, 0.0)}, 0.85),  # > LNDMC_ROT_MAX
        ("pushing up", {}, 1.0),  # no low thrust
    ],
)
def test_movement_or_thrust_keeps_it_from_landing(what: str, state: dict, lift: float) -> None:
    assert feed(flying(), 5.0, descent=0.5, lift=lift, **state) is None, what


def test_a_yaw_rate_alone_does_not_count_as_rotation() -> None:
    assert feed(flying(), 2.0, descent=0.5, rates=(0.0, 0.0, 1.0)) is not None


def test_once_landed_it_needs_no_descent_and_tolerates_2_5x_the_movement() -> None:
    ld = flying()
    assert feed(ld, 2.0, descent=0.3) is not None
    assert feed(ld, 3.0, descent=0.0, lift=0.25, t0=2.0) is not None  # idling on the ground
    assert ld.landed
    feed(ld, 1.0, descent=0.0, lift=0.25, t0=5.0, velocity=(0.0, 0.0, 0.5), rates=(math.radians(40.0), 0.0, 0.0))
    assert ld.landed  # 0.5 < 2.5 x 0.25 m/s, 40 < 2.5 x 20 deg/s
    for i in range(3):
        ld.update(ground_state(6.0 + i * DT, velocity=(0.0, 0.0, -0.7)), 0.0, 0.25, armed=True)
    assert not ld.landed  # climbing away: at once (a step per stage, as PX4 judges on the last)


def test_disarmed_it_is_landed() -> None:
    ld = flying()
    for i in range(round(1.1 / DT)):
        ld.update(ground_state(i * DT, velocity=(0.0, 0.0, 1.0)), math.nan, 1.0, armed=False)
    assert ld.landed


def test_configure_changes_the_thresholds_and_the_trigger_time() -> None:
    ld = flying()
    ld.configure(AutopilotConfig(land_z_vel_max_m_s=0.2, land_trigger_time_s=3.0))
    landed_after = feed(ld, 5.0, descent=0.26)  # 0.26 > 1.1 x 0.2
    assert landed_after == pytest.approx(3.0, abs=0.05)


# ---------------------------------------------------------------- the vehicle


def descend(v: SimVehicle, down_m_s: float, seconds: float) -> dict[str, float | None]:
    """From an episode start, descend at ``down_m_s`` (OFFBOARD velocity); times after the
    touchdown at which the vehicle was landed and disarmed (None: never)."""
    sp = TargetFields(FRAME_LOCAL_NED, VELOCITY_ONLY, 0, 0, 0, 0, 0, down_m_s, 0, 0)
    v.offboard_setpoint(sp)
    assert v.request_mode(Mode.OFFBOARD)[0] == M.MAV_RESULT_ACCEPTED
    out: dict[str, float | None] = {"touchdown": None, "landed": None, "disarmed": None}
    for i in range(round(seconds / v.dynamics.dt_s)):
        if i % 12 == 0:
            v.offboard_setpoint(sp)
        v.step()
        for key, now in (("touchdown", v.touchdown is not None), ("landed", v.landed), ("disarmed", not v.armed)):
            if now and out[key] is None:
                out[key] = v.time_s
    td = out["touchdown"]
    return {k: (None if t is None or td is None else t - td) for k, t in out.items()} | {"touchdown": td}


def near_the_ground(seed: int, cfg: SitlConfig | None = None) -> SimVehicle:
    """An episode start, then held 0.3 m above the pad's roof: slow descents reach it soon."""
    v = make_vehicle(cfg or SitlConfig())
    v.reset_episode(seed=seed)
    pad = v.world.pad_ned(v.time_s)
    goto = TargetFields(FRAME_LOCAL_NED, 0b110111111000, pad[0], pad[1], pad[2] - 0.3 - v.height_offset_m, 0, 0, 0, 0, 0)
    v.offboard_setpoint(goto)
    v.request_mode(Mode.OFFBOARD)
    for i in range(round(10.0 / v.dynamics.dt_s)):
        if i % 12 == 0:
            v.offboard_setpoint(goto)
        v.step()
    return v


def test_a_slow_descent_touches_down_but_the_vehicle_never_lands_nor_disarms() -> None:
    v = near_the_ground(seed=21)
    t = descend(v, 0.26, 15.0)
    assert t["touchdown"] is not None and v.touchdown is not None and v.touchdown.success  # ground truth
    assert t["landed"] is None and t["disarmed"] is None
    assert v.armed and v.state.on_ground and not v.landed
    assert extended_sys_state(v).landed_state == M.MAV_LANDED_STATE_IN_AIR


def test_a_descent_of_0_3_lands_after_the_trigger_time_and_disarms() -> None:
    v = near_the_ground(seed=21)
    t = descend(v, 0.30, 8.0)
    assert t["landed"] == pytest.approx(1.0, abs=0.2)
    assert t["disarmed"] == pytest.approx(t["landed"] + 2.0, abs=0.05)  # COM_DISARM_LAND
    assert extended_sys_state(v).landed_state == M.MAV_LANDED_STATE_ON_GROUND


def test_the_contact_rule_keeps_the_old_outcome_for_the_slow_descent() -> None:
    v = near_the_ground(seed=21, cfg=CONTACT)
    t = descend(v, 0.26, 8.0)
    assert t["landed"] == 0.0  # landed at the touchdown
    assert t["disarmed"] is not None and 2.0 < t["disarmed"] < 2.5  # COM_DISARM_LAND (after a bounce)
    assert "LNDMC_Z_VEL_MAX" not in {p.name for p in v.params}  # and its parameter list is as before


def test_param_set_of_lndmc_z_vel_max_lowers_the_threshold() -> None:
    v = near_the_ground(seed=21)
    handler = MessageHandler(v, TelemetryScheduler(), None)
    out = handler.handle(M.MAVLink_param_set_message(1, 1, b"LNDMC_Z_VEL_MAX", 0.2, M.MAV_PARAM_TYPE_REAL32))
    (reply,) = out.replies
    assert reply.message.param_id == "LNDMC_Z_VEL_MAX" and reply.message.param_value == pytest.approx(0.2)
    t = descend(v, 0.26, 8.0)  # 0.26 > 1.1 x 0.2
    assert t["landed"] == pytest.approx(1.0, abs=0.2)


def test_the_land_parameters_are_served_like_the_others() -> None:
    v = SimVehicle(SitlConfig())
    handler = MessageHandler(v, TelemetryScheduler(), None)
    listed = [o.message for o in handler.handle(M.MAVLink_param_request_list_message(1, 1)).replies]
    values = {m.param_id: m.param_value for m in listed}
    assert values["LNDMC_Z_VEL_MAX"] == pytest.approx(0.25)
    assert values["LNDMC_XY_VEL_MAX"] == pytest.approx(1.5)
    assert values["LNDMC_ROT_MAX"] == pytest.approx(20.0)
    assert values["LNDMC_TRIG_TIME"] == pytest.approx(1.0)
    assert [m.param_index for m in listed] == list(range(len(listed))) and listed[0].param_count == len(listed)
    (read,) = handler.handle(M.MAVLink_param_request_read_message(1, 1, b"LNDMC_TRIG_TIME", -1)).replies
    assert read.message.param_id == "LNDMC_TRIG_TIME" and read.message.param_value == pytest.approx(1.0)
    assert v.set_param("LNDMC_TRIG_TIME", encode_value(99.0, M.MAV_PARAM_TYPE_REAL32))
    assert v.params.get("LNDMC_TRIG_TIME") == 10.0  # clamped to the range
    assert v.land_detector.px4._landed.delay_s == pytest.approx(10.0 / 3)


def test_auto_land_lands_and_disarms_within_a_few_seconds_of_touching_down() -> None:
    v = SimVehicle(SitlConfig())
    v.reset_episode(seed=22)
    v.land()
    touchdown = None
    for _ in range(round(25.0 / v.dynamics.dt_s)):
        v.step()
        if v.touchdown is not None and touchdown is None:
            touchdown = v.time_s
        if not v.armed:
            break
    assert touchdown is not None and not v.armed and v.landed
    assert 1.0 < v.time_s - touchdown < 4.0
    assert v.mode is Mode.AUTO_LAND


def test_armed_on_the_ground_it_stays_landed_idling_until_asked_to_take_off() -> None:
    v = SimVehicle(SitlConfig())
    v.arm()
    for _ in range(round(3.0 / v.dynamics.dt_s)):
        v.step()
    assert v.landed and v.armed and v.controller.lift_ratio < 0.3  # PX4's ground idle
    v.takeoff(math.nan)
    for _ in range(round(8.0 / v.dynamics.dt_s)):
        v.step()
    assert not v.landed and v.mode is Mode.AUTO_LOITER
    assert -v.state.position_ned_m[2] == pytest.approx(2.5, abs=0.15)


def test_the_ardupilot_personality_keeps_the_contact_rule() -> None:
    cfg = SitlConfig.model_validate({"personality": {"autopilot": "ardupilot"}})
    assert cfg.autopilot.land_detector == "px4"  # the default, which ArduCopter does not follow
    v = make_vehicle(cfg)
    assert v.land_rule() == "contact"
    assert not any(p.name.startswith("LNDMC_") for p in v.params)
