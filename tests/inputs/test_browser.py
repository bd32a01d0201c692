"""The console page's gamepad as a human input: the Xbox layout, repairs, a state that is not a
whole pad refused (never centred sticks), and the hold when the page falls silent while the
person flies, with its reason."""

from __future__ import annotations

import math

import pytest

from companion.config import PilotConfig
from companion.inputs.base import HumanCommand
from companion.inputs.browser import BrowserInput, command_from_gamepad, pad_shape_error
from companion.msg.command import JoystickCommand

TRIGGER = [0.0] * 7 + [1.0]
RELEASED = [0.0] * 8


def message(axes: list[float], buttons: list[float]) -> dict[str, object]:
    return {"type": "input", "axes": axes, "buttons": buttons, "seq": 1, "t": 0.0}


@pytest.mark.parametrize("axes,expected", [
    ([0, 0, 0, -1], JoystickCommand(0, 1, 0, 0)),  # right stick up: forward
    ([0, 0, 1, 0], JoystickCommand(1, 0, 0, 0)),   # right stick right: move right
    ([1, 0, 0, 0], JoystickCommand(0, 0, 1, 0)),   # left stick right: turn clockwise
    ([0, -1, 0, 0], JoystickCommand(0, 0, 0, 1)),  # left stick up: climb
])
def test_the_xbox_layout_of_the_paper(axes: list[float], expected: JoystickCommand) -> None:
    human, repaired = command_from_gamepad(axes, RELEASED, 0.5)
    assert human == HumanCommand(expected, override_held=False) and repaired == 0


def test_the_right_trigger_is_the_override_past_its_threshold() -> None:
    assert command_from_gamepad([0, 0, 0, 0], [0] * 7 + [0.6], 0.5)[0].override_held
    assert not command_from_gamepad([0, 0, 0, 0], [0] * 7 + [0.4], 0.5)[0].override_held
    assert not command_from_gamepad([0, 0, 0, 0], [0] * 7 + [math.nan], 0.5)[0].override_held


def test_odd_axes_are_repaired_and_counted() -> None:
    human, repaired = command_from_gamepad([math.nan, "x", 3.0, None], RELEASED, 0.5)
    assert human.command == JoystickCommand(1.0, 0.0, 0.0, 0.0) and repaired == 4


@pytest.mark.parametrize("axes,buttons,why", [
    ([], RELEASED, "reports 0 axes"),
    ([0.0, -0.5], TRIGGER, "reports 2 axes"),  # a pad with one stick: not the right stick held still
    ([0.0, 0.0, 0.0], TRIGGER, "reports 3 axes"),
    ([0.0, 0.0, 0.0, -0.5], [], "reports 0 buttons"),  # no trigger: not "released"
    ([0.0, 0.0, 0.0, -0.5], [1.0] * 7, "reports 7 buttons"),
])
def test_a_pad_that_is_not_a_pad_is_refused_never_centred(axes: list[float], buttons: list[float], why: str) -> None:
    with pytest.raises(ValueError, match=why):
        command_from_gamepad(axes, buttons, 0.5)
    source, _ = make()
    with pytest.raises(ValueError, match=why):
        source.feed(message(axes, buttons))
    status = source.status()
    assert status.messages == 0 and not status.fresh  # nothing fed: no centred sticks to fly or record
    assert source.read().hold


def test_the_keyboards_whole_pad_and_longer_pads_are_read() -> None:
    assert pad_shape_error(4, 8) is None and pad_shape_error(16, 32) is None  # the keyboard's state: 4 axes, 8 buttons
    source, _ = make()
    source.feed(message([0.0, -0.6, 0.0, 0.0, 0.3, 0.3], [0.0] * 7 + [1.0] + [0.0] * 9))  # an Xbox pad: 6 axes, 17 buttons
    assert source.read() == HumanCommand(JoystickCommand(0, 0, 0, 0.6), override_held=True)


def test_a_message_without_lists_is_refused() -> None:
    for bad in ({"axes": 3, "buttons": []}, {"buttons": RELEASED}, {"axes": "0000", "buttons": RELEASED}):
        with pytest.raises(ValueError, match="axes"):
            BrowserInput(PilotConfig()).feed(bad)


class Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def make() -> tuple[BrowserInput, Clock]:
    clock = Clock()
    source = BrowserInput(PilotConfig(manual_timeout_s=0.5), clock=clock)
    source.connected()
    return source, clock


def test_fresh_sticks_are_read_as_sent() -> None:
    source, _ = make()
    source.feed(message([0, 0, 0, -0.5], TRIGGER))
    assert source.read() == HumanCommand(JoystickCommand(0, 0.5, 0, 0), override_held=True)


def test_silence_without_override_is_a_hold_that_keeps_nobody_in_charge() -> None:
    source, clock = make()
    assert source.read() == HumanCommand(JoystickCommand.neutral(), override_held=False, hold=True)
    source.feed(message([0, 0, 0, -0.5], RELEASED))
    clock.t += 0.6
    assert source.read() == HumanCommand(JoystickCommand.neutral(), override_held=False, hold=True)
    assert source.status().hold_reason is None


def test_a_page_lost_while_holding_the_override_latches_a_hold() -> None:
    source, clock = make()
    source.feed(message([0, 0, 0, -0.5], TRIGGER))
    source.disconnected()
    held = HumanCommand(JoystickCommand.neutral(), override_held=True, hold=True)
    assert source.read() == held
    assert "lost its link" in (source.status().hold_reason or "")
    clock.t += 1.0
    source.feed(message([0, 0, 0, -0.5], RELEASED))  # back, trigger released: still holding
    assert source.read() == held
    source.feed(message([0, 0, 0, -0.5], TRIGGER))  # the person takes the sticks again
    assert source.read() == HumanCommand(JoystickCommand(0, 0.5, 0, 0), override_held=True)
    assert source.status().hold_reason is None


def test_a_stale_page_latches_too_and_hand_back_releases_to_the_policy() -> None:
    source, clock = make()
    source.feed(message([0, 0, 0, 0], TRIGGER))
    clock.t += 0.6
    assert source.read().hold and source.read().override_held
    source.feed(message([0, 0, 0, 0], RELEASED))
    assert source.read().hold
    source.hand_back()
    assert source.read() == HumanCommand(JoystickCommand.neutral(), override_held=False)


def test_a_new_episode_starts_without_a_latched_hold() -> None:
    source, _ = make()
    source.feed(message([0, 0, 0, 0], TRIGGER))
    source.disconnected()
    assert source.read().hold
    source.feed(message([0, 0, 0, 0], RELEASED))
    source.reset()
    assert not source.read().hold


def test_the_hold_names_why_the_input_is_missing() -> None:
    source, clock = make()
    assert source.status().lost_reason == "the pilot's page has sent no input yet"
    source.feed(message([0, 0, 0, -0.5], RELEASED))
    assert source.status().lost_reason is None and source.why_holding() is None
    clock.t += 0.6
    assert "sent no input for more than 0.5 s" in (source.status().lost_reason or "")
    source.feed(message([0, 0, 0, -0.5], RELEASED))
    source.refused("this gamepad reports 2 axes; the console needs 4")
    assert source.status().lost_reason is None  # the last good input is still fresh ...
    clock.t += 0.6  # ... and ages out: the hold names the refusal, not a lost link
    assert source.status().lost_reason == "the pilot's input is refused (this gamepad reports 2 axes; the console needs 4)"
    assert source.status().connected
    source.disconnected("the pilot (page 3) gave up the role")
    assert source.why_holding() == "the pilot (page 3) gave up the role"
    source.connected()
    assert source.status().lost_reason == "the pilot's page has sent no input yet"


@pytest.mark.parametrize("leave,why", [
    (lambda s: s.disconnected("the pilot (page 2) gave up the role"), "the pilot (page 2) gave up the role"),
    (lambda s: s.disconnected("the pilot's page 2 lost its link to the console"), "the pilot's page 2 lost its link to the console"),
    (lambda s: s.refused("input refused: axes[0] = 5.0 is outside [-1, 1]"),
     "the pilot's input is refused (input refused: axes[0] = 5.0 is outside [-1, 1])"),
    (lambda s: None, "the pilot's page sent no input for more than 0.5 s"),
])
def test_a_latched_hold_names_its_real_reason(leave, why: str) -> None:  # type: ignore[no-untyped-def]
    source, clock = make()
    source.feed(message([0, 0, 0, -0.5], TRIGGER))
    leave(source)
    clock.t += 0.6
    assert source.read() == HumanCommand(JoystickCommand.neutral(), override_held=True, hold=True)
    assert source.status().hold_reason == f"{why} while the person held the override"
    assert source.why_holding() == source.status().hold_reason
