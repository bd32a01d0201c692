"""The console page's gamepad as a human input: the Xbox layout, repairs, and the hold when the
page falls silent while the person flies."""

from __future__ import annotations

import math

import pytest

from companion.commands import JoystickCommand
from companion.config import PilotConfig
from companion.inputs.base import HumanCommand
from companion.inputs.browser import BrowserInput, command_from_gamepad

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
    assert not command_from_gamepad([0, 0, 0, 0], [], 0.5)[0].override_held


def test_odd_axes_are_repaired_and_counted() -> None:
    human, repaired = command_from_gamepad([math.nan, "x", 3.0, None], RELEASED, 0.5)
    assert human.command == JoystickCommand(1.0, 0.0, 0.0, 0.0) and repaired == 4
    human, repaired = command_from_gamepad([], RELEASED, 0.5)  # missing axes: centred
    assert human.command == JoystickCommand.neutral() and repaired == 0


def test_a_message_without_lists_is_refused() -> None:
    with pytest.raises(ValueError, match="axes"):
        BrowserInput(PilotConfig()).feed({"axes": 3, "buttons": []})


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
