"""The touchdown assist, the home frame, and ArduCopter's confirmed GUIDED before arming:
pure logic on snapshots and in-memory links, no sockets."""

from __future__ import annotations

from dataclasses import replace

import pytest

from companion.config import CompanionConfig, LandingConfig
from companion.control.safety import SetpointLimiter
from companion.control.sequences import take_off
from companion.control.touchdown import (
    TouchdownAssist,
    TouchdownNeed,
    VehicleTouchdown,
    touchdown_need,
)
from companion.errors import CommandRejected, LinkError
from companion.link.dialect import ARDUPILOT
from companion.link.home import HomeFrame
from companion.msg.setpoint import VelocitySetpoint
from companion.msg.snapshot import VehicleSnapshot
from tests.control.test_sequences import DialectLink

PERIOD_S = 1 / 10.5


def snap(down_m: float = 0.0, vz: float = 0.0, landed: str = "IN_AIR", armed: bool = True,
         home_down: float | None = None, autopilot: str = "PX4") -> VehicleSnapshot:
    return VehicleSnapshot(
        received_s=0.0, time_boot_ms=0, frame_time_boot_ms=None, system_id=1, autopilot=autopilot, armed=armed,
        mode="OFFBOARD", landed_state=landed, position_ned_m=(1.0, 2.0, down_m), velocity_ned_m_s=(0.0, 0.0, vz),
        attitude_rad=(0.0, 0.0, 0.0), rates_frd_rad_s=(0.0, 0.0, 0.0), heartbeat_s=0.0, position_valid=True,
        home_ned_m=None if home_down is None else (0.0, 0.0, home_down),
    )


def test_px4_needs_what_its_land_detector_parameter_says() -> None:
    need = touchdown_need("PX4", {"LNDMC_Z_VEL_MAX": 0.3}.get)
    assert need.min_descent_m_s == pytest.approx(0.33)
    assert "LNDMC_Z_VEL_MAX 0.3" in need.why
    assert touchdown_need("PX4", lambda name: None).min_descent_m_s == pytest.approx(0.275)  # PX4's default
    assert touchdown_need("ARDUPILOTMEGA", {"LAND_SPEED": 50.0}.get).min_descent_m_s == 0.0
    assert touchdown_need("PX4", lambda name: 0.3, configured_m_s=0.5).min_descent_m_s == 0.5


def _assist(home: HomeFrame | None = None, **cfg: object) -> TouchdownAssist:
    need = TouchdownNeed(0.275, "PX4 test")
    return TouchdownAssist(need, LandingConfig(**cfg), PERIOD_S, pad_height_m=1.5, home=home or HomeFrame())


SLOW = VelocitySetpoint(0.1, 0.0, 0.263, 0.0)
LANDING = LandingConfig()


def test_standing_on_the_ground_while_asked_down_slowly_asks_what_px4_needs() -> None:
    assist = _assist()
    sent = [assist.apply(SLOW, snap(down_m=0.0)) for _ in range(15)]
    window = assist.window_steps
    assert all(sp == SLOW for sp in sent[: window - 1])  # not yet: a second of evidence first
    assert all(sp.down_m_s == pytest.approx(0.275 * 1.2) for sp in sent[window - 1:])
    assert sent[-1].forward_m_s == SLOW.forward_m_s  # only the descent changes


def test_a_vehicle_descending_as_asked_is_left_alone() -> None:
    assist = _assist()
    down = -3.0
    for _ in range(40):
        down += SLOW.down_m_s * PERIOD_S
        assert assist.apply(SLOW, snap(down_m=down, vz=0.263)) == SLOW
    assert not assist.engaged


def test_the_assist_lets_go_when_the_pilot_stops_asking_down_and_acts_only_low() -> None:
    assist = _assist()
    for _ in range(15):
        assist.apply(SLOW, snap(down_m=0.0))
    assert assist.engaged
    hover = VelocitySetpoint(0.0, 0.0, 0.0, 0.0)
    assert assist.apply(hover, snap(down_m=0.0)) == hover and not assist.engaged
    high = _assist()  # standing still high above the pad (a stall in the air): not a surface
    assert all(high.apply(SLOW, snap(down_m=-5.0)) == SLOW for _ in range(30))


def test_the_assist_is_off_where_the_detector_needs_no_descent_or_when_switched_off() -> None:
    off = _assist(touchdown_assist=False)
    ardu = TouchdownAssist(TouchdownNeed(0.0, "ArduCopter"), LandingConfig(), PERIOD_S, 1.5, HomeFrame())
    for assist in (off, ardu):
        assert not assist.active
        assert all(assist.apply(SLOW, snap(down_m=0.0)) == SLOW for _ in range(30))


def test_evidence_of_touchdown_needs_evidence_touchdown_s_of_standing() -> None:
    assist = _assist(evidence_touchdown_s=1.0)
    results = [(assist.apply(SLOW, snap()), assist.standing_long_enough())[1] for _ in range(40)]
    first = results.index(True)
    assert first == assist.window_steps - 1 + assist.evidence_steps - 1


def test_home_frame_without_home_or_standing_changes_nothing() -> None:
    home = HomeFrame()
    s = snap(down_m=-3.25)
    home.update(s)
    assert home.origin is None
    assert home.relative(s) is s.position_ned_m  # the very tuple: bit-identical observations
    assert home.to_vehicle((1.0, 2.0, -3.0)) == (1.0, 2.0, -3.0)


def test_home_frame_takes_the_ground_it_stood_on_over_a_jumpy_home_position() -> None:
    home = HomeFrame()
    for z in (-1.5, -0.5, 0.3, -0.9, -0.6):  # PX4 SIH's HOME_POSITION z, message by message
        home.update(snap(down_m=-4.0, home_down=z))
    assert home.origin == (0.0, 0.0, -0.6)  # their median
    for _ in range(10):
        home.update(snap(down_m=-0.5, landed="ON_GROUND", armed=False, home_down=-0.6))
    assert home.origin == (0.0, 0.0, -0.5)
    assert home.height(snap(down_m=-3.0)) == pytest.approx(2.5)
    assert home.to_vehicle((0.0, 0.0, -2.0)) == (0.0, 0.0, -2.5)
    home.update(snap(down_m=-3.0))  # a flight
    # standing disarmed on the pad's roof, 1.5 m up: a raised surface, the ground stays
    for _ in range(10):
        home.update(snap(down_m=-2.0, landed="ON_GROUND", armed=False))
    assert home.origin == (0.0, 0.0, -0.5)
    home.update(snap(down_m=-3.0))
    for _ in range(10):  # back on the ground, which has drifted by 0.4 m: the new ground level
        home.update(snap(down_m=-0.1, landed="ON_GROUND", armed=False))
    assert home.origin == (0.0, 0.0, -0.1)


class LaggingGuided(DialectLink):
    """ArduCopter that ACKs GUIDED while its EKF settles but stays in STABILIZE a while."""

    def __init__(self, ignored_mode_changes: int, refuse_takeoff_once: bool = False,
                 disarms_before_takeoff: bool = False) -> None:
        super().__init__(ARDUPILOT, landed="ON_GROUND")
        self.armed = False
        self.mode = "STABILIZE"
        self.ignored = ignored_mode_changes
        self.refuse_takeoff_once = refuse_takeoff_once
        self.disarms_before_takeoff = disarms_before_takeoff
        self.really_armed = False  # what the vehicle is; ``armed`` is what its last HEARTBEAT said

    def arm(self) -> None:
        super().arm()
        self.really_armed = True

    def set_mode(self, name: str) -> None:
        self.calls.append(f"mode {name}")
        if self.ignored > 0:
            self.ignored -= 1
            return
        self.mode = name

    def takeoff(self, alt_m: float) -> None:
        if self.disarms_before_takeoff:  # its disarm after the landing fired; no HEARTBEAT since
            self.disarms_before_takeoff = self.really_armed = False
        if not self.really_armed:
            self.calls.append("takeoff refused")
            raise CommandRejected("takeoff", "FAILED", ARDUPILOT.takeoff_hint)
        if self.refuse_takeoff_once:
            self.refuse_takeoff_once = False
            self.mode = "STABILIZE"  # as if the mode had reverted
            self.calls.append("takeoff refused")
            raise CommandRejected("takeoff", "FAILED")
        super().takeoff(alt_m)


def test_arducopter_arms_only_once_guided_shows_in_the_heartbeat() -> None:
    link = LaggingGuided(ignored_mode_changes=2)
    clock = [0.0]
    take_off(link, ARDUPILOT, 2.5, arm_timeout_s=60.0, sleep=lambda s: clock.__setitem__(0, clock[0] + s),
             clock=lambda: clock[0])
    assert link.calls == ["mode GUIDED", "mode GUIDED", "mode GUIDED", "arm", "takeoff 2.5"]


def test_a_takeoff_refused_outside_guided_enters_guided_again_and_retries() -> None:
    link = LaggingGuided(ignored_mode_changes=0, refuse_takeoff_once=True)
    clock = [0.0]
    take_off(link, ARDUPILOT, 2.5, arm_timeout_s=60.0, sleep=lambda s: clock.__setitem__(0, clock[0] + s),
             clock=lambda: clock[0])
    assert link.calls == ["mode GUIDED", "arm", "takeoff refused", "mode GUIDED", "arm", "takeoff 2.5"]


def test_a_takeoff_refused_because_the_vehicle_disarmed_meanwhile_arms_again_and_retries() -> None:
    link = LaggingGuided(ignored_mode_changes=0, disarms_before_takeoff=True)
    clock = [0.0]
    take_off(link, ARDUPILOT, 2.5, arm_timeout_s=60.0, sleep=lambda s: clock.__setitem__(0, clock[0] + s),
             clock=lambda: clock[0])
    assert link.state().mode == "GUIDED" and link.state().armed  # its HEARTBEAT never said otherwise
    assert link.calls == ["mode GUIDED", "arm", "takeoff refused", "arm", "takeoff 2.5"]


def test_a_takeoff_refused_again_after_the_retry_raises_with_the_vehicles_reason() -> None:
    link = LaggingGuided(ignored_mode_changes=0)
    link.arm = lambda: link.calls.append("arm")  # type: ignore[method-assign]  # ACKed, never armed
    with pytest.raises(CommandRejected, match="takeoff"):
        take_off(link, ARDUPILOT, 2.5, arm_timeout_s=60.0, sleep=lambda s: None, clock=lambda: 0.0)
    assert link.calls == ["mode GUIDED", "arm", "takeoff refused", "arm", "takeoff refused"]


def test_a_snapshot_keeps_home_through_other_messages() -> None:
    s = snap(home_down=-0.7)
    assert replace(s, armed=False).home_ned_m == (0.0, 0.0, -0.7)


def test_standing_asks_the_vehicles_own_landing_descent_when_it_is_faster() -> None:
    need = touchdown_need("PX4", {"LNDMC_Z_VEL_MAX": 0.25, "MPC_LAND_SPEED": 0.7}.get)
    assert need.min_descent_m_s == pytest.approx(0.275) and need.land_speed_m_s == 0.7
    assist = TouchdownAssist(need, LandingConfig(), PERIOD_S, 1.5, HomeFrame())
    sent = [assist.apply(SLOW, snap(down_m=0.0)) for _ in range(15)]
    assert sent[-1].down_m_s == pytest.approx(0.7)
    absurd = touchdown_need("PX4", {"LNDMC_Z_VEL_MAX": 0.25, "MPC_LAND_SPEED": 3.0}.get)
    assert absurd.land_speed_m_s == 0.0  # beyond 1 m/s is not asked of a vehicle on the ground


def test_the_fence_floor_does_not_stop_a_vehicle_standing_on_a_surface() -> None:
    from companion.control.safety import Geofence

    fence = Geofence(30.0, -1.0, 25.0)
    assert not fence.check((0.0, 0.0, 1.4)).inside  # 1.4 m below home in the air: outside
    assert fence.check((0.0, 0.0, 1.4), standing=True).inside  # standing: the estimate drifted
    assert not fence.check((40.0, 0.0, 1.4), standing=True).inside  # the radius still counts


def test_a_rangefinder_at_the_surface_is_standing_at_once_and_a_touchdown_after_the_evidence_time() -> None:
    assist = _assist(evidence_touchdown_s=1.0)
    sinking = -0.5
    for step in range(30):  # PX4 SIH: the estimate sinks at 0.2 m/s while the vehicle stands
        sinking += 0.2 * PERIOD_S
        s = replace(snap(down_m=sinking, vz=0.2), ground_distance_m=0.0, ground_distance_s=0.0)
        sent = assist.apply(SLOW, s)
        if step == 2:
            assert assist.engaged and sent.down_m_s == pytest.approx(0.33)  # three readings of contact
    assert assist.range_contact_long_enough()
    stale = replace(snap(down_m=-5.0), ground_distance_m=0.0, ground_distance_s=-10.0)
    fresh = _assist()
    assert all(fresh.apply(SLOW, stale) == SLOW for _ in range(20))  # an old reading says nothing


def test_the_rangefinder_reading_is_folded_only_from_a_downward_sensor_in_its_range() -> None:
    from pymavlink.dialects.v20 import common as mavlink

    from companion.link.telemetry import _distance_sensor

    def msg(cm: int, orientation: int = 25) -> object:
        return mavlink.MAVLink_distance_sensor_message(0, 0, 10000, cm, 0, 0, orientation, 0)

    assert _distance_sensor(msg(48), 3.0) == {"ground_distance_m": 0.48, "ground_distance_s": 3.0}
    assert _distance_sensor(msg(65519), 3.0)["ground_distance_m"] == 0.0  # PX4 SIH's -17 cm, wrapped: the surface
    assert _distance_sensor(msg(20000), 3.0)["ground_distance_m"] is None  # beyond its range: no reading
    assert _distance_sensor(msg(48, orientation=0), 3.0) == {}  # forward-looking: not the ground


def test_the_assist_after_the_limiter_keeps_to_the_limiters_bounds() -> None:
    """It comes after the limiter (a land detector needs a descent the rate limit would spread
    out), so it must itself never ask for more than the limiter lets through: a vehicle whose
    landing descent (2.5 m/s here) is above the commands' v_z_max gets v_z_max."""
    cfg = CompanionConfig()
    limiter = SetpointLimiter(cfg.commands, cfg.safety)
    need = TouchdownNeed(0.275, "PX4 test", land_speed_m_s=2.5)
    assist = TouchdownAssist(need, LandingConfig(), PERIOD_S, pad_height_m=1.5, home=HomeFrame(),
                             max_down_m_s=limiter.max_down_m_s)
    sent = [assist.apply(limiter.apply(SLOW, PERIOD_S), snap(down_m=0.0)) for _ in range(30)]
    assert assist.engaged and max(sp.down_m_s for sp in sent) == cfg.commands.v_z_max_m_s
    c = cfg.commands
    bounds = (c.v_xy_max_m_s, c.v_xy_max_m_s, c.v_z_max_m_s, c.yaw_rate_max_rad_s)
    assert all(abs(a) <= b for sp in sent for a, b in zip(sp.as_tuple(), bounds, strict=True))


class ParamLink:
    """A vehicle that says its autopilot and answers parameters (or cannot yet: ``error``)."""

    def __init__(self, autopilot: str | None, params: dict[str, float], error: Exception | None = None) -> None:
        self.autopilot, self.params, self.error = autopilot, params, error
        self.asked: list[str] = []

    def state(self) -> VehicleSnapshot | None:
        return None if self.autopilot is None else snap(autopilot=self.autopilot)

    def read_param(self, name: str) -> float | None:
        self.asked.append(name)
        if self.error is not None:
            raise self.error
        return self.params.get(name)


def _vehicle(link: ParamLink, landing: LandingConfig | None = LANDING) -> VehicleTouchdown:
    return VehicleTouchdown(landing, PERIOD_S, 1.5, HomeFrame(), max_down_m_s=1.0, link=link)  # type: ignore[arg-type]


def test_a_vehicles_assist_is_made_once_from_its_own_parameters_and_reset_each_episode() -> None:
    link = ParamLink("PX4", {"LNDMC_Z_VEL_MAX": 0.3})
    touchdown = _vehicle(link)
    touchdown.reset()
    assist = touchdown.assist
    assert assist is not None and assist.need.min_descent_m_s == pytest.approx(0.33)
    for _ in range(assist.window_steps):
        assist.apply(SLOW, snap(down_m=0.0))
    assert assist.engaged
    touchdown.reset()
    assert touchdown.assist is assist and not assist.engaged  # the same assist, started afresh
    assert link.asked == ["LNDMC_Z_VEL_MAX", "MPC_LAND_SPEED"]  # asked once


def test_no_assist_without_landing_or_switched_off_and_none_until_the_vehicle_answers() -> None:
    for landing in (None, LandingConfig(touchdown_assist=False)):
        link = ParamLink("PX4", {})
        touchdown = _vehicle(link, landing)
        touchdown.reset()
        assert touchdown.assist is None and link.asked == []
    silent = ParamLink("PX4", {}, error=LinkError("no HEARTBEAT"))
    touchdown = _vehicle(silent)
    touchdown.reset()
    assert touchdown.assist is None
    silent.error = None
    touchdown.reset()  # asked again at the next episode
    assert touchdown.assist is not None and touchdown.assist.need.min_descent_m_s == pytest.approx(0.275)
    unknown = _vehicle(ParamLink(None, {}))
    unknown.reset()  # no HEARTBEAT at all: no known descent rule, nothing to add
    assert unknown.assist is not None and not unknown.assist.active
