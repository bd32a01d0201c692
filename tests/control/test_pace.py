"""The record says when the companion fell behind the vehicle's clock (companion/control/pace.py)."""

from __future__ import annotations

from companion.control.pace import achieved_rate_hz, pace_note


def test_a_kept_rate_says_nothing() -> None:
    assert pace_note(500, 50.0, 10.0) is None  # the experiment's 500 steps in 50 s of the vehicle's
    assert pace_note(400, 50.0, 10.0) is None  # 8 a second: at the limit, still kept


def test_steps_that_fell_behind_the_vehicle_are_said_with_the_rate() -> None:
    note = pace_note(500, 80.06, 10.0)  # CI at load 12: PX4 SIH at 4x, 500 steps in 80 s of its time
    assert note is not None and note.startswith("control kept 6.2 of 10 steps a second of the vehicle's time")


def test_too_short_an_episode_or_no_steps_tells_nothing() -> None:
    assert achieved_rate_hz(3, 1.0) is None and pace_note(3, 1.0, 10.0) is None
    assert achieved_rate_hz(0, 30.0) is None and pace_note(0, 30.0, 10.0) is None
    assert achieved_rate_hz(50, 10.0) == 5.0
