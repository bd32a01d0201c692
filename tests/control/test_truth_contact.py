"""A touchdown by a SITL's truth (companion/control/truth_contact.py): the ground where the vehicle
stood disarmed, the first contact with it ending the episode as a touchdown with a note, and
nothing without a level, without fresh truth, or unless asked for."""

from __future__ import annotations

import dataclasses

import pytest

from companion.config import SessionConfig
from companion.control.outcome import TIMEOUT, TOUCHDOWN, Verdict, judge_vehicle
from companion.control.safety import Geofence
from companion.control.touchdown import TRUTH_CONTACT_NOTE
from companion.control.truth_contact import TruthGround
from companion.errors import ConfigError
from companion.link.home import HomeFrame
from companion.msg.snapshot import VehicleSnapshot
from companion.msg.true_pose import TruePose

GROUND_DOWN_M = 0.44  # PX4 SIH's truth stands off the local origin's altitude, by another amount each boot


def snap(true_down_m: float | None, *, armed: bool = True, landed: str = "LANDING", t_ms: int = 5000,
         truth_ms: int | None = None) -> VehicleSnapshot:
    """The vehicle's estimate at 1 m; its SITL's truth at ``true_down_m`` (None: no truth)."""
    truth = None if true_down_m is None else TruePose(0.2, -0.1, true_down_m, (0.0, 0.0, 0.0),
                                                      t_ms if truth_ms is None else truth_ms, "SIM_STATE", 1.0)
    return VehicleSnapshot(1.0, t_ms, t_ms, 1, "ARDUPILOTMEGA", armed, "LAND", landed, (0.0, 0.0, -1.0),
                           (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0.0, True, True,
                           home_ned_m=(0.0, 0.0, 0.0), true_pose=truth)


def measured() -> TruthGround:
    ground = TruthGround(contact_m=0.05)
    ground.observe_standing(snap(GROUND_DOWN_M, armed=False, landed="ON_GROUND"))
    return ground


def test_the_ground_is_where_the_truth_stood_disarmed_and_only_there() -> None:
    ground = TruthGround()
    ground.observe_standing(snap(-3.0, armed=True, landed="IN_AIR"))  # flying: not the ground
    ground.observe_standing(snap(GROUND_DOWN_M, armed=True, landed="ON_GROUND"))  # armed: may be lifting off
    ground.observe_standing(snap(None, armed=False, landed="ON_GROUND"))  # no truth
    assert ground.ground_down_m is None
    assert measured().ground_down_m == GROUND_DOWN_M


def test_contact_is_within_contact_m_of_that_ground_on_fresh_truth() -> None:
    ground = measured()
    assert not ground.touching(snap(GROUND_DOWN_M - 0.06))
    assert ground.touching(snap(GROUND_DOWN_M - 0.05))
    assert ground.height_m(snap(GROUND_DOWN_M - 0.05)) == pytest.approx(0.05)
    assert ground.touching(snap(GROUND_DOWN_M + 0.01))  # sunk a little on its gear
    assert not ground.touching(snap(GROUND_DOWN_M, truth_ms=4700))  # 300 ms old: says nothing of this frame
    assert not ground.touching(snap(None))
    assert not TruthGround().touching(snap(GROUND_DOWN_M))  # no level measured: no contact


def test_the_first_contact_ends_the_episode_as_a_touchdown_with_its_note() -> None:
    fence, home = Geofence(30.0, -1.0, 25.0), HomeFrame()
    above = snap(GROUND_DOWN_M - 0.3)
    assert judge_vehicle(3, 10, above, fence, home, ground=measured()) == Verdict(None)
    verdict = judge_vehicle(3, 10, snap(GROUND_DOWN_M), fence, home, ground=measured())
    assert verdict.outcome == TOUCHDOWN and verdict.evidence is not None
    assert verdict.evidence.note == TRUTH_CONTACT_NOTE
    assert verdict.evidence.stand_down  # the vehicle's own detector may never fire: the session disarms it
    assert "while it said LANDING" in verdict.evidence.message
    # not asked (no ground given): the vehicle's own landed state judges, as before
    assert judge_vehicle(3, 10, snap(GROUND_DOWN_M), fence, home) == Verdict(None)
    assert judge_vehicle(10, 10, snap(GROUND_DOWN_M), fence, home, ground=measured()) == Verdict(TIMEOUT)
    # the vehicle's own word comes first, with no note
    on_ground = dataclasses.replace(snap(GROUND_DOWN_M), landed_state="ON_GROUND")
    assert judge_vehicle(3, 10, on_ground, fence, home, ground=measured()) == Verdict(TOUCHDOWN)


def test_the_setting_is_off_by_default_and_checked() -> None:
    assert not SessionConfig().touchdown_by_truth_contact
    with pytest.raises((ConfigError, ValueError)):
        SessionConfig(truth_contact_m=0.0)
