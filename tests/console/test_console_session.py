"""The console session's hand on a run, without a vehicle: next, stop, pause and the ready gate
between episodes, refused starts, discarding the last episode, the history a restarted console
reads, and the step message the page draws its HUD from."""

from __future__ import annotations

import json
import threading
from pathlib import Path

import numpy as np
import pytest

from companion.config import CompanionConfig
from companion.console.session import (
    STOPPED,
    ConsoleOptions,
    ConsoleSession,
    Hud,
    _EpisodeWatch,
    step_message,
)
from companion.control.arbiter import Decision, Phase
from companion.control.records import StepView
from companion.errors import ConfigError
from companion.learning.dataset import HumanDataset, load_csv
from companion.msg.command import JoystickCommand
from companion.msg.observation import Observation
from companion.msg.pad import PadDetection
from companion.msg.sample import Sample, Source
from companion.msg.setpoint import VelocitySetpoint


@pytest.fixture
def session(tmp_path: Path) -> ConsoleSession:
    published: list[dict] = []
    s = ConsoleSession(CompanionConfig(), ConsoleOptions(run_dir=tmp_path / "run"), published.append, lambda b: None)
    s.published = published  # type: ignore[attr-defined]
    return s


def _waiting(session: ConsoleSession, episode: int, phase: Phase = Phase.INTERVENTION) -> tuple[threading.Thread, list[bool]]:
    answer: list[bool] = []
    waiter = threading.Thread(target=lambda: answer.append(session.before_episode(episode, phase)))
    waiter.start()
    return waiter, answer


def test_next_ends_one_episode_and_stop_ends_the_run(session: ConsoleSession) -> None:
    session.set_auto(True)
    assert session.before_episode(0, Phase.INTERVENTION)
    assert session.end_requested() is None
    session.next_episode()
    assert session.end_requested() == STOPPED
    assert session.end_requested() is None  # only this episode
    session.stop()
    assert session.end_requested() == STOPPED
    assert not session.before_episode(1, Phase.INTERVENTION)


def test_idle_controls_are_refused_not_ignored(session: ConsoleSession) -> None:
    for action, why in [(session.next_episode, "no episode is flying"), (session.stop, "no run to stop"),
                        (session.go, "no episode is waiting"), (lambda: session.discard_last("x"), "no finished episode")]:
        with pytest.raises(ConfigError, match=why):
            action()


def test_the_ready_gate_waits_for_the_pilots_go(session: ConsoleSession) -> None:
    waiter, answer = _waiting(session, 5)
    try:
        while session.status()["run"]["state"] != "ready":
            waiter.join(0.01)
        assert session.status()["run"]["ready_for"] == 5 and waiter.is_alive()
        session.go()
        waiter.join(10.0)
        assert answer == [True] and session.status()["run"]["episode"] == 5
    finally:
        session.close()


def test_pause_holds_the_next_episode_until_resumed(session: ConsoleSession) -> None:
    session.set_auto(True)
    session.pause(True)
    waiter, answer = _waiting(session, 3, Phase.DEMONSTRATION)
    while session.status()["run"]["state"] != "paused":
        waiter.join(0.01)
    assert waiter.is_alive()
    session.pause(False)
    waiter.join(10.0)
    assert answer == [True] and session.status()["run"]["episode"] == 3


@pytest.mark.parametrize("condition,episodes,why", [("eval", 2, "condition"), ("col", 0, "episodes"),
                                                    ("col", True, "episodes"), ("demo", 1001, "episodes"),
                                                    ("demo", 2.5, "episodes")])
def test_bad_starts_are_refused(session: ConsoleSession, condition: str, episodes: int, why: str) -> None:
    with pytest.raises(ConfigError, match=why):
        session.start(condition, episodes)
    assert not session.running


def _record(episode: int, phase: str = "demonstration") -> dict:
    return {"episode": episode, "phase": phase, "outcome": "timeout", "success": False, "steps": 500,
            "human_samples": 3, "interventions": 0, "touchdown_distance_m": None, "dataset_size": 3 * (episode + 1),
            "policy_version": 7, "loss_all": 0.01, "seed": 1}


def _write_run(run_dir: Path) -> None:
    run_dir.mkdir(parents=True)
    lines = [json.dumps(_record(0)), json.dumps(_record(1)), '{"episode": 2, "pha']  # a torn last line
    (run_dir / "episodes.jsonl").write_text("\n".join(lines))
    (run_dir / "console.jsonl").write_text(json.dumps({"episode": 1, "touchdown_ne_m": None, "no_stick_input": True}) + "\n")
    with HumanDataset(run_dir / "human.csv") as ds:
        for ep in (0, 1):
            ds.extend(Sample(ep, i, i * 0.1, Source.DEMONSTRATION, np.zeros(15), np.zeros(4)) for i in range(3))


def test_a_restarted_console_shows_the_history_and_can_discard_the_last_episode(tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    _write_run(run_dir)
    published: list[dict] = []
    s = ConsoleSession(CompanionConfig(), ConsoleOptions(run_dir=run_dir), published.append, lambda b: None)
    hello = s.hello()
    assert [r["episode"] for r in hello["records"]] == [0, 1]
    assert hello["records"][1]["no_stick_input"] and not hello["records"][0]["no_stick_input"]
    s.discard_last("nobody flew it")
    assert any(m["type"] == "discarded" and m["episode"] == 1 and m["rows"] == 3 for m in published)
    with pytest.raises(ConfigError, match="already"):
        s.discard_last("again")
    assert len(load_csv(run_dir / "human.csv").episode) == 6  # nothing deleted
    again = ConsoleSession(CompanionConfig(), ConsoleOptions(run_dir=run_dir), published.append, lambda b: None)
    assert again.hello()["records"][1]["discarded"] == "nobody flew it"
    with HumanDataset(run_dir / "human.csv") as ds:
        assert len(ds) == 3


def _view(pad: PadDetection | None, down_m: float = -5.0, step: int = 17) -> StepView:
    obs = Observation((1.0, 2.0, down_m), (0.0, 0.0, -0.5), (3.0, 4.0, 0.4), (0.0, 0.0, 0.0), pad, (320, 240), 1234)
    decision = Decision(JoystickCommand.neutral(), "human", False, None)
    return StepView(2, step, Phase.INTERVENTION, obs, decision, VelocitySetpoint(0.0, 0.0, 0.0, 0.0), 42, True, True, 99)


def test_a_step_as_the_page_sees_it() -> None:
    m = step_message(_view(PadDetection(100.0, 80.0, 12.0, False)), float("nan"), 99)
    assert m["who"] == "hold" and m["altitude_m"] == 5.0 and m["climb_m_s"] == -0.4
    assert m["height_above_pad_m"] == 3.5  # the pad is 1.5 m up
    assert m["ground_speed_m_s"] == 5.0 and m["heading_deg"] == pytest.approx(331.4, abs=0.1)
    assert m["time_left_s"] == round((500 - 18) / 10.5, 1) and m["frame_number"] == 99
    assert m["pad"] == {"u": 100.0, "v": 80.0, "r": 12.0, "partial": False} and not m["pad_fills_image"]
    assert m["loss"] is None and m["samples"] == 99 and m["policy_version"] == 42
    assert m["position_ne_m"] == [1.0, 2.0]
    assert str(step_message(_view(None, down_m=-2.0), None, 0)["climb_m_s"]) == "-0.4"


def test_a_pad_too_close_to_see_is_said_to_fill_the_image() -> None:
    watch = _EpisodeWatch(pad_k_px_m=60.0 * 3.5)  # 60 px at 3.5 m above the pad
    assert step_message(_view(None, down_m=-2.5), None, 0, Hud(), watch)["pad_fills_image"]  # 1 m: 210 px
    assert not step_message(_view(None, down_m=-5.0), None, 0, Hud(), watch)["pad_fills_image"]
    assert not step_message(_view(None, down_m=-2.5), None, 0, Hud(), _EpisodeWatch())["pad_fills_image"]


def test_the_runs_status_reaches_the_pages_before_its_first_step(session: ConsoleSession) -> None:
    """The 4 Hz status trails the steps: the session publishes its status itself when the run
    is connected and when each episode starts, so no page sees a step of a run it thinks is starting."""
    from types import SimpleNamespace

    vehicle = SimpleNamespace(camera=None, simulator=SimpleNamespace(address="127.0.0.1:4567"))
    learner = SimpleNamespace(latest_snapshot=SimpleNamespace(version=3), last_loss=None)
    session.started(vehicle, learner, [])  # type: ignore[arg-type]
    statuses = [m for m in session.published if m["type"] == "status"]  # type: ignore[attr-defined]
    assert statuses and statuses[-1]["run"]["state"] == "running" and statuses[-1]["simulator"] == "127.0.0.1:4567"
    session.set_auto(True)
    assert session.before_episode(4, Phase.DEMONSTRATION)
    last = [m for m in session.published if m["type"] == "status"][-1]  # type: ignore[attr-defined]
    assert last["run"]["episode"] == 4 and last["run"]["phase"] == "demonstration" and last["run"]["state"] == "running"


def test_a_hold_step_names_why_the_person_holds(session: ConsoleSession) -> None:
    session.human.connected()
    session.human.refused("this gamepad reports 2 axes; the console needs 4")
    session.on_step(_view(None))  # a step the person's missing input holds
    step = [m for m in session.published if m["type"] == "step"][-1]  # type: ignore[attr-defined]
    assert step["who"] == "hold"
    assert step["hold_reason"] == "the pilot's input is refused (this gamepad reports 2 axes; the console needs 4)"
    assert session.status()["input"]["lost_reason"] == step["hold_reason"]
