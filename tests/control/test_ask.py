"""Asking for help: the state machine alone, then whole episodes against the lockstep SITL
(in-process: the SITL's own frame loop, autopilot and MAVLink handling, in this process).

The policy in the SITL tests is an ensemble of random networks (they disagree everywhere) and
the threshold is set to 0, so the request comes at the first step; the people are scripted.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from companion.app import RunOptions
from companion.commands import CommandMapper
from companion.config import AskConfig, CompanionConfig
from companion.control.arbiter import Phase
from companion.control.ask import AskAction, AskEvent, HelpAsker, threshold_for
from companion.control.parts import EpisodeParts
from companion.control.safety import Geofence, SetpointLimiter
from companion.control.session import EpisodeRunner
from companion.inprocess import inprocess_vehicle
from companion.inputs.base import HelpRequest, HumanCommand, HumanInput
from companion.learning.dataset import HumanDataset
from companion.learning.ensemble import EnsembleSnapshot
from companion.learning.policy import PolicyNet, PolicySnapshot
from companion.msg.command import JoystickCommand
from companion.msg.observation import Observation
from companion.vision.observer import Observer
from companion.vision.perception import PadDetector

PERIOD_S = 1 / 10.5


def _asker(**kw: object) -> tuple[HelpAsker, list[AskEvent]]:
    events: list[AskEvent] = []
    cfg = AskConfig(enabled=True, **kw)  # type: ignore[arg-type]
    return HelpAsker(cfg, PERIOD_S, events.append), events


def test_threshold_is_the_quantile_of_the_target_rate() -> None:
    scores = np.arange(1000, dtype=float)
    assert threshold_for(scores, 0.02, 64) == pytest.approx(np.quantile(scores, 0.98))
    assert threshold_for(scores[:10], 0.02, 64) == math.inf  # too few samples: never ask
    assert threshold_for(np.array([np.nan] * 100 + [1.0] * 100), 0.5, 64) == 1.0


def test_request_answer_hand_back_rearm_and_timeout() -> None:
    asker, events = _asker(rearm_s=1.0, answer_timeout_s=1.0, on_timeout="land")
    asker.threshold = 0.5
    assert asker.step(0, 0.1, False) is AskAction.POLICY
    assert asker.step(1, 0.9, False) is AskAction.HOLD and asker.wants_person
    assert asker.step(2, 0.9, False) is AskAction.HOLD
    assert asker.step(3, 0.9, True) is AskAction.PERSON
    assert asker.step(4, 0.9, True) is AskAction.PERSON
    assert asker.step(5, 0.9, False) is AskAction.POLICY  # handed back: re-armed for 1 s
    rearm = round(1.0 / PERIOD_S)
    assert all(asker.step(6 + i, 0.9, False) is AskAction.POLICY for i in range(rearm))
    assert asker.step(100, 0.9, False) is AskAction.HOLD  # asks again
    actions = [asker.step(101 + i, 0.9, False) for i in range(round(1.0 / PERIOD_S) + 1)]
    assert actions[-1] is AskAction.LAND and asker.step(200, 0.0, True) is AskAction.LAND
    summary = asker.end_episode(201)
    assert [e.kind for e in events] == ["request", "answered", "handed_back", "request", "unanswered"]
    assert (summary.requests, summary.answered, summary.unanswered) == (2, 1, 1)
    assert summary.response_steps == (2,)
    assert events[0].request is not None and events[0].request.number == 1 and events[3].request.number == 2
    assert summary.engaged_steps == 4 + len(actions) - 1 + 1  # request 1: 4 steps; request 2: until LAND


def test_an_unasked_take_over_counts_as_engaged_and_hold_without_timeout_holds() -> None:
    asker, events = _asker(on_timeout="hold", answer_timeout_s=0.5)
    asker.threshold = math.inf
    assert asker.step(0, 1e9, True) is AskAction.PERSON  # a person who watches anyway
    assert asker.step(1, 1e9, False) is AskAction.POLICY
    asker.threshold, asker._rearm_steps = 0.0, 0
    assert all(asker.step(2 + i, 1.0, False) is AskAction.HOLD for i in range(40))
    summary = asker.end_episode(50)
    assert summary.unanswered == 0 and summary.engaged_steps == 1 + 40
    assert [e.kind for e in events] == ["handed_back", "request", "ended"]


# ----- against the SITL ---------------------------------------------------------------------------

class _Frozen:
    def __init__(self, snapshot: PolicySnapshot) -> None:
        self.latest_snapshot = snapshot
        self.error = None

    def on_control_step(self, tick_start_s: float | None = None) -> PolicySnapshot:
        return self.latest_snapshot


class ScriptedPerson(HumanInput):
    """Answers request ``answer`` (1-based; 0: none) ``delay`` steps late, flies ``fly``
    steps descending slowly, and lets go. Keeps the positions it saw and the requests."""

    def __init__(self, *, answer: int, delay: int = 5, fly: int = 15, gated: bool = True) -> None:
        self.answer, self.delay, self.fly = answer, delay, fly
        self.robot_gated = gated
        self.requests: list[HelpRequest | None] = []
        self.seen: list[tuple[float, ...]] = []
        self._countdown: int | None = None
        self._flying = 0

    def on_request(self, request: HelpRequest | None) -> None:
        self.requests.append(request)
        if request is not None and request.number == self.answer:
            self._countdown = self.delay

    def read(self, obs: Observation) -> HumanCommand:
        self.seen.append(tuple(float(v) for v in obs.position_ned_m))
        if self._countdown is not None:
            self._countdown -= 1
            if self._countdown <= 0:
                self._countdown, self._flying = None, self.fly
        if self._flying > 0:
            self._flying -= 1
            return HumanCommand(JoystickCommand(0.0, 0.0, 0.0, -0.3), True)
        return HumanCommand.neutral()


def _ensemble() -> EnsembleSnapshot:
    import torch

    members = [PolicyNet(generator=torch.Generator().manual_seed(s), init_std=0.3).snapshot() for s in range(5)]
    return EnsembleSnapshot.of_members(members)


@pytest.fixture
def vehicle(tmp_path: Path) -> Iterator[tuple[CompanionConfig, object]]:
    cfg = CompanionConfig()
    with inprocess_vehicle(cfg, RunOptions(seed=3), True, tmp_path) as v:
        yield cfg, v


def _runner(cfg: CompanionConfig, v: object, person: ScriptedPerson, ask: AskConfig, max_steps: int,
            texts: list[str]) -> tuple[EpisodeRunner, HumanDataset, list[AskEvent]]:
    link = v.link  # type: ignore[attr-defined]
    send = link.send_statustext

    def spy(text: str, severity: int = 4) -> bool:
        texts.append(text)
        return bool(send(text, severity))

    link.send_statustext = spy
    events: list[AskEvent] = []
    dataset = HumanDataset(None)  # empty at the start: nothing to recalibrate on, the threshold stays 0
    asker = HelpAsker(ask, PERIOD_S)
    asker.threshold = 0.0
    parts = EpisodeParts(
        link=link, observer=Observer(v.camera, PadDetector(cfg.perception), (320, 240), 2.0),  # type: ignore[attr-defined]
        mapper=CommandMapper(cfg.commands), human=person, fence=Geofence.from_config(cfg.safety),
        limiter=SetpointLimiter(cfg.commands, cfg.safety),
        cfg=cfg.session.model_copy(update={"max_steps": max_steps}), lockstep=True,
        simulator=v.simulator, runner=_Frozen(_ensemble()), dataset=dataset, asker=asker,  # type: ignore[attr-defined]
        on_ask_event=events.append)
    return EpisodeRunner(parts), dataset, events


def test_a_request_holds_the_vehicle_where_it_asked(vehicle: tuple[CompanionConfig, object]) -> None:
    cfg, v = vehicle
    person = ScriptedPerson(answer=0, gated=False)  # watches, never answers
    texts: list[str] = []
    runner, dataset, events = _runner(cfg, v, person, AskConfig(enabled=True, answer_timeout_s=60.0), 80, texts)
    record = runner.run(0, Phase.INTERVENTION, seed=3)
    assert record.outcome == "timeout" and record.steps == 80
    assert [w for _, _, w in runner.trace] == ["hold"] * 80
    assert all(s > 0 for _, s, _ in runner.trace)  # random members disagree
    positions = np.array(person.seen)
    drift = np.abs(positions - positions[0]).max(axis=0)
    assert drift[0] < 0.3 and drift[1] < 0.3 and drift[2] < 0.3, drift  # 7.6 s of position hold
    assert record.requests == 1 and record.requests_unanswered == 0 and record.human_samples == 0
    assert record.supervised_steps == 80  # this person watched throughout
    assert texts == ["COL: unsure, holding - take over (1)"]
    assert [e.kind for e in events] == ["request", "ended"]
    assert person.requests[0] is not None and person.requests[-1] is None and len(dataset) == 0


def test_a_take_over_after_a_request_is_recorded_as_an_intervention(vehicle: tuple[CompanionConfig, object]) -> None:
    cfg, v = vehicle
    person = ScriptedPerson(answer=1, delay=5, fly=15)  # watches only when asked
    ask = AskConfig(enabled=True, answer_timeout_s=60.0, rearm_s=1.0)
    runner, dataset, events = _runner(cfg, v, person, ask, 60, [])
    record = runner.run(0, Phase.INTERVENTION, seed=3)
    who = [w for _, _, w in runner.trace]
    assert who[:5] == ["hold"] * 5 and who[5:20] == ["human"] * 15
    assert "policy" in who[20:] and who[-1] == "hold"  # flew again, then asked again
    assert record.interventions == 1 and record.human_samples == 15 == len(dataset)
    view = dataset.view()
    assert view.intervention is not None and view.intervention.all()
    assert np.allclose(view.actions[:, 3], -0.3)
    assert record.requests == 2
    assert [e.kind for e in events] == ["request", "answered", "handed_back", "request", "ended"]
    assert events[1].waited_steps == 5
    policy_steps = who.count("policy")
    assert record.supervised_steps == record.steps - policy_steps  # away while the policy flew
    # read only from the step after each request until the hand-back: steps 1-20 and 32-59
    assert len(person.seen) == 20 + 28 and policy_steps == 11


def test_an_unanswered_request_lands(vehicle: tuple[CompanionConfig, object]) -> None:
    cfg, v = vehicle
    person = ScriptedPerson(answer=0)
    texts: list[str] = []
    ask = AskConfig(enabled=True, answer_timeout_s=2.0, on_timeout="land")
    runner, dataset, events = _runner(cfg, v, person, ask, 500, texts)
    record = runner.run(0, Phase.INTERVENTION, seed=3)
    assert record.outcome == "touchdown", record
    who = [w for _, _, w in runner.trace]
    timeout_steps = math.ceil(2.0 / PERIOD_S)
    assert who[:timeout_steps] == ["hold"] * timeout_steps and set(who[timeout_steps:]) == {"land"}
    assert record.requests == 1 and record.requests_unanswered == 1 and len(dataset) == 0
    assert any("unanswered" in n for n in record.notes)
    assert texts == ["COL: unsure, holding - take over (1)", "COL: no answer, landing"]
    assert [e.kind for e in events] == ["request", "unanswered"]
    state = v.link.state()  # type: ignore[attr-defined]
    assert state is not None and state.landed_state == "ON_GROUND"
