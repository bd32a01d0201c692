"""The console session's hand on a run, without a vehicle: next, stop, pause between episodes,
refused starts, and the step message the page draws its HUD from."""

from __future__ import annotations

import threading
from pathlib import Path

import pytest

from companion.commands import JoystickCommand
from companion.config import CompanionConfig
from companion.console.session import STOPPED, ConsoleOptions, ConsoleSession, step_message
from companion.control.arbiter import Decision, Phase
from companion.control.session import StepView
from companion.errors import ConfigError
from companion.link.setpoints import VelocitySetpoint
from companion.vision.observation import Observation
from companion.vision.perception import PadDetection


@pytest.fixture
def session(tmp_path: Path) -> ConsoleSession:
    published: list[dict] = []
    s = ConsoleSession(CompanionConfig(), ConsoleOptions(run_dir=tmp_path / "run"), published.append, lambda b: None)
    s.published = published  # type: ignore[attr-defined]
    return s


def test_next_ends_one_episode_and_stop_ends_the_run(session: ConsoleSession) -> None:
    assert session.before_episode(0, Phase.INTERVENTION)
    assert session.end_requested() is None
    session.next_episode()
    assert session.end_requested() == STOPPED
    assert session.end_requested() is None  # only this episode
    session.stop()
    assert session.end_requested() == STOPPED
    assert not session.before_episode(1, Phase.INTERVENTION)


def test_pause_holds_the_next_episode_until_resumed(session: ConsoleSession) -> None:
    session.pause(True)
    answer: list[bool] = []
    waiter = threading.Thread(target=lambda: answer.append(session.before_episode(3, Phase.DEMONSTRATION)))
    waiter.start()
    waiter.join(0.3)
    assert waiter.is_alive() and session.status()["run"]["state"] == "paused"
    session.pause(False)
    waiter.join(2.0)
    assert answer == [True] and session.status()["run"]["episode"] == 3


@pytest.mark.parametrize("condition,episodes,why", [("eval", 2, "condition"), ("col", 0, "episodes"),
                                                    ("col", True, "episodes"), ("demo", 1001, "episodes")])
def test_bad_starts_are_refused(session: ConsoleSession, condition: str, episodes: int, why: str) -> None:
    with pytest.raises(ConfigError, match=why):
        session.start(condition, episodes)
    assert not session.running


def test_a_step_as_the_page_sees_it() -> None:
    obs = Observation((1.0, 2.0, -5.0), (0.0, 0.0, 0.5), (0.0, 0.0, 0.4), (0.0, 0.0, 0.0),
                      PadDetection(100.0, 80.0, 12.0, False), (320, 240), 1234)
    decision = Decision(JoystickCommand.neutral(), "human", False, None)
    view = StepView(2, 17, Phase.INTERVENTION, obs, decision, VelocitySetpoint(0.0, 0.0, 0.0, 0.0), 42, True, True)
    m = step_message(view, float("nan"), 99)
    assert m["who"] == "hold" and m["altitude_m"] == 5.0 and m["climb_m_s"] == -0.4
    assert m["pad"] == {"u": 100.0, "v": 80.0, "r": 12.0, "partial": False}
    assert m["loss"] is None and m["samples"] == 99 and m["policy_version"] == 42
    assert m["position_ne_m"] == [1.0, 2.0]
