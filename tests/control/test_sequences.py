"""Per dialect: take-off, waiting to be armable, hold (geofence), land and the end-of-run state,
on in-memory vehicles that record what they were asked, in order."""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np
import pytest

from companion.control.arbiter import Phase
from companion.control.sequences import arm_when_ready, leave_safe, take_off, when_ready
from companion.errors import CommandRejected, ConfigError, LinkError
from companion.link.dialect import ARDUPILOT, PX4, Dialect, Step, dialect_for
from companion.msg.snapshot import VehicleSnapshot
from tests.control.test_session import KinematicLink, ScriptedHuman, make_runner, policy_runner

AUTOPILOT = {"PX4": "PX4", "ArduPilot": "ARDUPILOTMEGA"}
START_MODE = {"PX4": "AUTO.LOITER", "ArduPilot": "BRAKE"}


class DialectLink(KinematicLink):
    """The kinematic vehicle speaking as ``autopilot``; it logs every call it gets, can refuse
    arming a number of times with a reason (as a booting vehicle), and knows its modes."""

    def __init__(self, dialect: Dialect, start_ned=(0.0, 0.0, -3.0), landed: str | None = None,  # type: ignore[no-untyped-def]
                 arm_refusals: int = 0) -> None:
        super().__init__(start_ned)
        self.dialect = dialect
        self.mode = START_MODE[dialect.name]
        self.calls: list[str] = []
        self.arm_refusals = arm_refusals
        self.landed = landed
        self.disarm_refused = False

    def _snap(self) -> VehicleSnapshot:
        snap = replace(super()._snap(), autopilot=AUTOPILOT[self.dialect.name])
        return replace(snap, landed_state=self.landed) if self.landed else snap

    def set_mode(self, name: str) -> None:
        if name not in (self.dialect.offboard_mode, self.dialect.hold_mode, self.dialect.land_mode):
            raise CommandRejected(f"set_mode({name!r})", "UNSUPPORTED", origin="companion")
        self.calls.append(f"mode {name}")
        super().set_mode(name)

    def arm(self) -> None:
        self.calls.append("arm")
        if self.arm_refusals > 0:
            self.arm_refusals -= 1
            raise CommandRejected("arm", "FAILED", reasons=("PreArm: EKF3 waiting for GPS config data",
                                                           "Arm: Need Position Estimate"))
        super().arm()

    def disarm(self) -> None:
        self.calls.append("disarm")
        if self.disarm_refused:
            raise CommandRejected("disarm", "DENIED", reasons=("Disarm refused: in the air",))
        super().disarm()

    def takeoff(self, alt_m: float) -> None:
        self.calls.append(f"takeoff {alt_m}")

    def send_position_ned(self, north_m: float, east_m: float, down_m: float, yaw_rad: float,  # type: ignore[override]
                          echo_time_boot_ms: int | None = None) -> None:
        self.pos = np.array([north_m, east_m, down_m])  # a point mass that is where it is asked to be

    def land(self) -> None:
        self.calls.append("land")


@pytest.fixture(params=[PX4, ARDUPILOT], ids=["px4", "ardupilot"])
def dialect(request: pytest.FixtureRequest) -> Dialect:
    return request.param


def test_the_dialect_comes_from_the_heartbeat_and_an_unknown_autopilot_is_explained() -> None:
    assert dialect_for("PX4") is PX4 and dialect_for("ARDUPILOTMEGA") is ARDUPILOT
    with pytest.raises(ConfigError, match="PX4 and ArduPilot"):
        dialect_for("GENERIC")
    assert PX4.offboard_mode == "OFFBOARD" and ARDUPILOT.offboard_mode == "GUIDED"
    assert ARDUPILOT.hold_mode == "BRAKE"  # the vehicle's own hold, never stick-driven LOITER
    assert PX4.lockstep_marker == "SYSTEM_TIME" and ARDUPILOT.lockstep_marker is None
    assert (PX4.loss_timeout_param, ARDUPILOT.loss_timeout_param) == ("COM_OF_LOSS_T", "GUID_TIMEOUT")
    assert PX4.body_frame == ARDUPILOT.body_frame == 8 and PX4.body_type_mask == ARDUPILOT.body_type_mask == 0x5C7


def test_take_off_follows_the_dialect(dialect: Dialect) -> None:
    link = DialectLink(dialect, landed="ON_GROUND")
    link.armed = False
    take_off(link, dialect, 2.5, arm_timeout_s=5.0)
    expected = [f"mode {'AUTO.LOITER' if dialect is PX4 else 'GUIDED'}", "arm", "takeoff 2.5"]
    assert link.calls == expected
    assert dialect.takeoff_steps(2.5)[-1] == Step("takeoff", alt_m=2.5)


def test_arming_waits_while_the_vehicle_is_not_ready_and_shows_its_reasons(caplog: pytest.LogCaptureFixture) -> None:
    link = DialectLink(ARDUPILOT, arm_refusals=3)
    link.armed = False
    sleeps: list[float] = []
    with caplog.at_level(logging.WARNING):
        when_ready(link.arm, "arm", timeout_s=60.0, sleep=sleeps.append)
    assert link.armed and link.calls == ["arm"] * 4 and sleeps == [1.0] * 3
    shown = [r.getMessage() for r in caplog.records if "waiting for the vehicle to arm" in r.getMessage()]
    assert len(shown) == 2  # each reason once, not once per attempt
    assert "PreArm: EKF3 waiting for GPS config data" in shown[0] and "Need Position Estimate" in shown[1]


def test_arming_gives_up_after_the_timeout_with_the_vehicles_reasons() -> None:
    link = DialectLink(ARDUPILOT, arm_refusals=100)
    link.armed = False
    t = [0.0]

    def sleep(s: float) -> None:
        t[0] += s

    with pytest.raises(CommandRejected) as info:
        when_ready(link.arm, "arm", timeout_s=5.0, sleep=sleep, clock=lambda: t[0])
    assert info.value.origin == "vehicle" and "Need Position Estimate" in str(info.value)
    assert "arm_timeout_s" in str(info.value) and 4 <= len(link.calls) <= 6


def test_a_refusal_by_the_companion_is_not_retried() -> None:
    link = DialectLink(ARDUPILOT)
    with pytest.raises(CommandRejected, match="without asking the vehicle") as info:
        when_ready(lambda: link.set_mode("OFFBOARD"), "enter OFFBOARD", timeout_s=60.0, sleep=pytest.fail)
    assert info.value.origin == "companion" and link.calls == []


def test_arm_when_ready_passes_at_once_when_the_vehicle_is_ready() -> None:
    link = DialectLink(PX4)
    link.armed = False
    arm_when_ready(link, 0.0)
    assert link.armed and link.calls == ["arm"]


@pytest.mark.parametrize("policy", ["land", "hold"])
def test_end_of_run_lands_or_holds_a_flying_vehicle(dialect: Dialect, policy: str) -> None:
    link = DialectLink(dialect)
    assert leave_safe(link, dialect, policy) == (dialect.land_mode if policy == "land" else dialect.hold_mode)  # type: ignore[arg-type]
    if policy == "hold":
        assert link.calls == [f"mode {dialect.hold_mode}"]
    else:  # PX4 lands by command (AUTO.LAND follows), ArduCopter by its LAND mode
        assert link.calls == (["land"] if dialect is PX4 else ["mode LAND"])


def test_end_of_run_disarms_on_the_ground_and_leaves_a_disarmed_vehicle_alone(dialect: Dialect) -> None:
    link = DialectLink(dialect, landed="ON_GROUND")
    assert leave_safe(link, dialect, "land") == "disarmed" and link.calls == ["disarm"]
    assert leave_safe(link, dialect, "land") == "disarmed" and link.calls == ["disarm"]  # nothing more


def test_end_of_run_lands_when_the_vehicle_refuses_to_disarm(dialect: Dialect) -> None:
    link = DialectLink(dialect, landed="ON_GROUND")
    link.disarm_refused = True
    leave_safe(link, dialect, "land")
    assert link.calls[0] == "disarm" and link.calls[1] in ("land", "mode LAND")


def test_end_of_run_with_the_link_lost_does_nothing_and_says_so(dialect: Dialect) -> None:
    link = DialectLink(dialect)
    link.alive = False
    assert leave_safe(link, dialect, "land") == "link lost" and link.calls == []


def test_an_episode_enters_the_dialects_offboard_mode(dialect: Dialect) -> None:
    link = DialectLink(dialect)
    runner, _ = make_runner(link, ScriptedHuman(set()), runner=policy_runner())
    record = runner.run(0, Phase.DEMONSTRATION, seed=1)
    assert record.outcome == "touchdown"
    assert link.calls[0] == f"mode {dialect.offboard_mode}"
    assert not any("OFFBOARD" in c for c in link.calls) or dialect is PX4


def test_the_geofence_holds_with_the_dialects_hold(dialect: Dialect) -> None:
    link = DialectLink(dialect)
    runner, _ = make_runner(link, ScriptedHuman(set()), fence_radius_m=0.5)
    record = runner.run(0, Phase.DEMONSTRATION, seed=1)
    assert record.outcome == "fence"
    assert link.calls[-1] == f"mode {dialect.hold_mode}"  # ArduCopter: BRAKE, never LOITER


def test_an_episode_error_leaves_the_vehicle_safe(dialect: Dialect) -> None:
    link = DialectLink(dialect)
    sent = link.send_velocity_body

    def refuse_after_five(sp, echo_time_boot_ms=None):  # type: ignore[no-untyped-def]
        if len(link.sent) >= 5:
            raise LinkError("the link refused a setpoint")
        sent(sp, echo_time_boot_ms)

    link.send_velocity_body = refuse_after_five  # type: ignore[method-assign]
    runner, _ = make_runner(link, ScriptedHuman(set()))
    runner.p.simulator = None  # a vehicle without episode resets: it flies to the start point
    record = runner.run(0, Phase.DEMONSTRATION, seed=1)
    assert record.outcome == "error" and "started by flying to the start point" in record.notes
    assert link.calls[-1] in ("land", "mode LAND")  # the default end_of_run policy


class DisarmsAsItTakesOff(DialectLink):
    """Stands armed on the ground after a landing; its auto-disarm fires on the first take-off
    (PX4 COM_DISARM_LAND, seen on PX4 SIH at 4x), the second one climbs."""

    def __init__(self, dialect: Dialect) -> None:
        super().__init__(dialect, start_ned=(0.0, 0.0, 0.0))
        self.takeoffs = 0

    def takeoff(self, alt_m: float) -> None:
        super().takeoff(alt_m)
        self.takeoffs += 1
        if self.takeoffs == 1:
            self.armed = False
        else:
            self.pos = np.array([0.0, 0.0, -alt_m])


def test_a_vehicle_that_disarms_itself_as_it_takes_off_is_taken_off_again(
        dialect: Dialect, caplog: pytest.LogCaptureFixture) -> None:
    link = DisarmsAsItTakesOff(dialect)
    runner, _ = make_runner(link, ScriptedHuman(set()))
    runner.p.simulator = None  # a vehicle without episode resets: it takes off and flies to the start point
    with caplog.at_level(logging.WARNING):
        record = runner.run(0, Phase.DEMONSTRATION, seed=1)
    assert link.takeoffs == 2 and link.calls.count("arm") == 2, link.calls
    assert "disarmed itself as it took off" in caplog.text
    assert record.outcome != "error" and "started by flying to the start point" in record.notes, record
