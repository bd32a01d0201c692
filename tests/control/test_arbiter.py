"""The arbiter: who flies each tick, what is recorded, and how interventions are counted."""

from __future__ import annotations

import pytest

from companion.control.arbiter import Arbiter, Decision, Phase
from companion.control.ask import AskAction
from companion.inputs.base import HumanCommand
from companion.msg.command import JoystickCommand

PERSON = JoystickCommand(roll=0.5, pitch=0.25, yaw=0.0, throttle=-0.5)
POLICY = JoystickCommand(roll=-0.75, pitch=0.0, yaw=0.125, throttle=0.5)


def human(held: bool) -> HumanCommand:
    return HumanCommand(PERSON, override_held=held)


@pytest.mark.parametrize("held", [False, True])
def test_demonstration_always_flies_and_records_the_person(held: bool) -> None:
    d = Arbiter().decide(Phase.DEMONSTRATION, human(held), POLICY)
    assert d == Decision(PERSON, "human", True, "demonstration")


def test_intervention_without_override_flies_the_policy_unrecorded() -> None:
    d = Arbiter().decide(Phase.INTERVENTION, human(False), POLICY)
    assert d == Decision(POLICY, "policy", False, None)


def test_intervention_with_override_flies_and_records_the_person() -> None:
    d = Arbiter().decide(Phase.INTERVENTION, human(True), POLICY)
    assert d == Decision(PERSON, "human", True, "intervention")


@pytest.mark.parametrize("held", [False, True])
def test_autonomous_always_flies_the_policy_and_never_records(held: bool) -> None:
    d = Arbiter().decide(Phase.AUTONOMOUS, human(held), POLICY)
    assert d == Decision(POLICY, "policy", False, None)


def test_switch_happens_in_the_tick_the_override_changes() -> None:
    arbiter = Arbiter()
    held = [False, False, True, True, False, True, False]
    decisions = [arbiter.decide(Phase.INTERVENTION, human(h), POLICY) for h in held]
    # Tick by tick, no lag in either direction.
    assert [d.source for d in decisions] == ["human" if h else "policy" for h in held]
    assert [d.command for d in decisions] == [PERSON if h else POLICY for h in held]
    assert [d.record for d in decisions] == held


def test_only_human_samples_are_recorded_across_phases() -> None:
    arbiter = Arbiter()
    recorded = []
    script = [(Phase.DEMONSTRATION, False)] * 3 + [(Phase.INTERVENTION, False)] * 2
    script += [(Phase.INTERVENTION, True)] * 2 + [(Phase.AUTONOMOUS, True)] * 2
    for phase, held in script:
        d = arbiter.decide(phase, human(held), POLICY)
        if d.record:
            recorded.append((d.command, d.tag))
    assert all(cmd == PERSON for cmd, _ in recorded)
    assert [tag for _, tag in recorded] == ["demonstration"] * 3 + ["intervention"] * 2


def test_interventions_counted_by_rising_edge_with_durations() -> None:
    arbiter = Arbiter()
    held = [False, True, True, True, False, False, True, False, True, True]
    for h in held:
        arbiter.decide(Phase.INTERVENTION, human(h), POLICY)
    s = arbiter.summary()
    assert s.interventions == 3
    assert s.durations_steps == (3, 1, 2)  # the last one is still running
    assert s.steps == 10 and s.human_steps == 6 and s.recorded_steps == 6
    assert s.durations_s(0.1) == pytest.approx((0.3, 0.1, 0.2))


def test_demonstrations_and_autonomy_count_no_interventions() -> None:
    arbiter = Arbiter()
    for h in [True, False, True]:
        arbiter.decide(Phase.DEMONSTRATION, human(h), POLICY)
        arbiter.decide(Phase.AUTONOMOUS, human(h), POLICY)
    s = arbiter.summary()
    assert s.interventions == 0
    assert (s.steps, s.human_steps, s.recorded_steps) == (6, 3, 3)


def test_reset_starts_a_new_episode_count() -> None:
    arbiter = Arbiter()
    arbiter.decide(Phase.INTERVENTION, human(True), POLICY)
    arbiter.reset()
    # Still held after the reset: that is a new intervention in the new episode.
    arbiter.decide(Phase.INTERVENTION, human(True), POLICY)
    s = arbiter.summary()
    assert (s.steps, s.interventions, s.durations_steps) == (1, 1, (1,))


def test_decision_refuses_inconsistent_combinations() -> None:
    with pytest.raises(ValueError, match="never the policy"):
        Decision(POLICY, "policy", True, "intervention")
    with pytest.raises(ValueError, match="tag"):
        Decision(PERSON, "human", True, None)
    with pytest.raises(ValueError, match="tag"):
        Decision(POLICY, "policy", False, "demonstration")
    with pytest.raises(ValueError, match="source"):
        Decision(PERSON, "pilot", False, None)  # type: ignore[arg-type]


def lost(held: bool) -> HumanCommand:
    """A source that can no longer vouch for the sticks (a console page gone silent)."""
    return HumanCommand(PERSON, override_held=held, hold=True)


@pytest.mark.parametrize("phase,held", [(Phase.DEMONSTRATION, False), (Phase.DEMONSTRATION, True),
                                        (Phase.INTERVENTION, True)])
def test_a_person_in_charge_whose_input_is_lost_hovers_unrecorded(phase: Phase, held: bool) -> None:
    d = Arbiter().decide(phase, lost(held), POLICY)
    assert d == Decision(JoystickCommand.neutral(), "human", False, None)


def test_a_lost_input_without_override_leaves_the_flying_policy_alone() -> None:
    d = Arbiter().decide(Phase.INTERVENTION, lost(False), POLICY)
    assert d == Decision(POLICY, "policy", False, None)


def test_a_hold_inside_an_intervention_neither_ends_it_nor_records_it() -> None:
    a = Arbiter()
    for h in (human(True), lost(True), lost(True), human(True), human(False)):
        a.decide(Phase.INTERVENTION, h, POLICY)
    s = a.summary()
    assert (s.interventions, s.durations_steps, s.recorded_steps, s.human_steps) == (1, (4,), 2, 4)


def test_hold_must_be_a_bool() -> None:
    with pytest.raises(TypeError, match="hold"):
        HumanCommand(PERSON, override_held=False, hold=1)  # type: ignore[arg-type]


@pytest.mark.parametrize("asked", [AskAction.HOLD, AskAction.LAND])
@pytest.mark.parametrize("held", [False, True])
def test_asking_for_help_holds_or_lands_over_both_and_records_nothing(asked: AskAction, held: bool) -> None:
    """The vehicle holds where it asked, or lands unanswered: nobody's command flies, so nothing
    is recorded or counted as recorded (a landing the person already holds the trigger over too)."""
    arbiter = Arbiter()
    d = arbiter.decide(Phase.INTERVENTION, human(held=held), POLICY, asked=asked)
    assert (d.source, d.record, d.command) == (asked.value, False, JoystickCommand.neutral())
    assert arbiter.summary().recorded_steps == 0
    flying = arbiter.decide(Phase.INTERVENTION, human(held=held), POLICY, asked=AskAction.PERSON)
    assert flying.source == ("human" if held else "policy")
