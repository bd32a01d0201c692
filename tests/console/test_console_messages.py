"""What a page may send, checked before anything acts on it: a state that is not a whole pad is
refused (never centred sticks), and every refusal is counted and told to the page, a broken
pad's run of them cheaply but never silently."""

from __future__ import annotations

import logging

import pytest

from companion.console.messages import REFUSAL_SEND_INTERVAL_S, RefusalLog, Refused, check_input

KEYBOARD = {"type": "input", "axes": [0.0, -0.6, 0.0, 0.0], "buttons": [0.0] * 7 + [1.0], "seq": 3, "t": 1.0}


@pytest.mark.parametrize("axes,buttons,why", [
    ([], [0.0] * 8, "this gamepad reports 0 axes; the console needs 4"),
    ([0.0, 0.5], [0.0] * 8, "this gamepad reports 2 axes; the console needs 4"),
    ([0.0, 0.0, 0.0, 0.5], [], "this gamepad reports 0 buttons; the console needs 8"),
    ([0.0, 0.0, 0.0, 0.5], [1.0] * 7, "this gamepad reports 7 buttons; the console needs 8"),
])
def test_a_pad_that_is_not_a_pad_is_refused(axes: list[float], buttons: list[float], why: str) -> None:
    with pytest.raises(Refused, match=why):
        check_input({"type": "input", "axes": axes, "buttons": buttons})


def test_the_keyboards_state_and_a_whole_pad_pass() -> None:
    assert check_input(KEYBOARD) == KEYBOARD
    pad = {"type": "input", "axes": [0.1] * 6, "buttons": [0.0] * 17}
    assert check_input(pad)["axes"] == [0.1] * 6


def test_a_bad_value_is_named_before_the_pads_shape() -> None:
    with pytest.raises(Refused, match=r"axes\[0\] = 5"):
        check_input({"type": "input", "axes": [5], "buttons": []})


class Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def test_every_refusal_is_counted_and_told_at_once_after_good_input_or_another_reason() -> None:
    clock = Clock()
    log = RefusalLog("1", logging.getLogger("test"), clock=clock)
    assert log.refused("bad pad") and log.count("bad pad") == 1  # the first: at once
    clock.t += 0.03
    assert not log.refused("bad pad")  # a broken pad at 30 messages/s: counted, told later
    clock.t += 0.03
    assert not log.refused("bad pad") and log.count("bad pad") == 3
    assert log.unsent() == [("bad pad", 3)] and log.unsent() == []  # the count goes out when the interval ends
    clock.t += REFUSAL_SEND_INTERVAL_S
    assert log.refused("bad pad") and log.count("bad pad") == 4  # at most every interval, with the count
    log.accepted()  # good input
    clock.t += 0.01
    assert log.refused("bad pad") and log.count("bad pad") == 5  # the same fault again: told at once
    clock.t += 0.01
    assert log.refused("unknown command") and log.count("unknown command") == 1  # another reason: at once
    clock.t += 0.01
    assert log.refused("bad pad") and log.count("bad pad") == 6  # and back: at once
    assert log.unsent() == [] and log.total == 7


def test_the_counts_kept_are_bounded() -> None:
    log = RefusalLog("1", logging.getLogger("test"), clock=Clock())
    for i in range(500):
        log.refused(f"unknown message type {i}")
    assert len(log.counts) <= 64 and log.count("unknown message type 499") == 1
