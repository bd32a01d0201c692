"""Asking for help: when the ensemble disagrees, hold the vehicle and ask the person.

The paper's limitation: the person must supervise the agent at all times. Here the agent
says when it needs them, as ThriftyDAgger (Hoque et al. 2021) does with its novelty signal:
the disagreement of an ensemble of policies (:mod:`companion.learning.ensemble`) is compared
with a threshold set from a target rate - the ``1 - target_rate`` quantile of the
disagreement on the states of the human dataset - recalibrated at every episode start as the
dataset grows. When the score crosses it in an intervention episode:

1. the vehicle holds its position (a position setpoint through the same setpoint stream),
2. a :class:`~companion.inputs.base.HelpRequest` goes out (the session sends it as STATUSTEXT
   to the ground stations, logs it, tells the human input and any listener),
3. the person takes over (the override, as in any intervention: recorded as one), flies,
   and lets go; the policy then flies at least ``rearm_s`` before it may ask again;
4. nobody answers within ``answer_timeout_s``: the vehicle lands (``on_timeout = "land"``)
   or keeps holding (``"hold"``).

:class:`HelpAsker` is only this state machine: it is told the score and whether the
override is held each step, and answers what the vehicle should do. It counts what the
person was asked for: requests, answers, and the steps they were engaged (from a request
until they hand back), the supervision time of a person who only watches when asked.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum
from typing import Literal

import numpy as np

from companion.config import AskConfig
from companion.inputs.base import HelpRequest

log = logging.getLogger(__name__)


class AskAction(Enum):
    """What the vehicle does this step."""

    POLICY = "policy"
    HOLD = "hold"
    PERSON = "person"
    LAND = "land"


EventKind = Literal["request", "answered", "unanswered", "handed_back", "ended"]


@dataclass(frozen=True)
class AskEvent:
    """A change a console or log shows: a request raised, answered, given up, handed back."""

    kind: EventKind
    request: HelpRequest | None
    step: int
    waited_steps: int = 0
    """Steps from the request to this event."""


@dataclass(frozen=True)
class AskSummary:
    """One episode's requests, for the episode record."""

    requests: int
    answered: int
    unanswered: int
    engaged_steps: int
    """Steps from each request (or unasked take-over) until the person handed back."""
    response_steps: tuple[int, ...]
    """For each answered request, the steps until the person took over."""


def threshold_for(scores: np.ndarray, target_rate: float, min_samples: int) -> float:
    """The ``1 - target_rate`` quantile of ``scores`` (infinite below ``min_samples``: never ask)."""
    finite = np.asarray(scores, dtype=float)
    finite = finite[np.isfinite(finite)]
    if len(finite) < min_samples:
        return math.inf
    return float(np.quantile(finite, 1.0 - target_rate))


class HelpAsker:
    """The request state machine of one session (see the module docstring)."""

    def __init__(self, cfg: AskConfig, control_period_s: float,
                 on_event: Callable[[AskEvent], None] | None = None) -> None:
        if not cfg.enabled:
            raise ValueError("HelpAsker needs [companion.ask] enabled = true")
        self.cfg = cfg
        self.period_s = control_period_s
        self.on_event = on_event
        self.threshold = math.inf
        self.requests_total = 0
        self.begin_episode(0)

    def calibrate(self, scores: np.ndarray) -> float:
        """Set the threshold from the disagreement on the dataset's states; returns it."""
        self.threshold = threshold_for(scores, self.cfg.target_rate, self.cfg.min_samples)
        return self.threshold

    def begin_episode(self, episode: int) -> None:
        self.episode = episode
        self.action = AskAction.POLICY
        self.request: HelpRequest | None = None
        self._since = 0
        self._rearm_steps = 0
        self._requests = self._answered = self._unanswered = self._engaged = 0
        self._responses: list[int] = []

    @property
    def wants_person(self) -> bool:
        """Whether the person should be watching now (a request is open or they fly)."""
        return self.action in (AskAction.HOLD, AskAction.PERSON)

    def step(self, step: int, score: float, override_held: bool) -> AskAction:
        """Advance one control step: the policy's disagreement, and the person's trigger."""
        if self.action is AskAction.LAND:
            return self.action
        if override_held:
            self._take_over(step)
        elif self.action is AskAction.PERSON:
            self._emit("handed_back", step)
            self.action, self.request = AskAction.POLICY, None
            self._rearm_steps = round(self.cfg.rearm_s / self.period_s)
        elif self.action is AskAction.HOLD:
            self._wait(step)
        elif self._rearm_steps > 0:
            self._rearm_steps -= 1
        elif score > self.threshold:
            self._raise(step, score)
        self._since += 1
        self._engaged += self.wants_person
        return self.action

    def _take_over(self, step: int) -> None:
        if self.action is AskAction.HOLD:
            self._answered += 1
            self._responses.append(self._since)
            self._emit("answered", step)
        elif self.action is not AskAction.PERSON:
            self._since = 0  # an unasked take-over: engaged from now
        self.action = AskAction.PERSON

    def _wait(self, step: int) -> None:
        if self._since * self.period_s < self.cfg.answer_timeout_s:
            return
        if self.cfg.on_timeout == "land":
            self._unanswered += 1
            self._emit("unanswered", step)
            self.action = AskAction.LAND

    def _raise(self, step: int, score: float) -> None:
        self.requests_total += 1
        self._requests += 1
        self.request = HelpRequest(self.requests_total, self.episode, step, round(float(score), 6),
                                   round(self.threshold, 6))
        self.action, self._since = AskAction.HOLD, 0
        self._emit("request", step)

    def end_episode(self, step: int) -> AskSummary:
        """The episode is over: close an open request (the person is told) and summarise."""
        if self.request is not None and self.action in (AskAction.HOLD, AskAction.PERSON):
            self._emit("ended", step)
        self.request = None
        return AskSummary(self._requests, self._answered, self._unanswered, self._engaged, tuple(self._responses))

    def _emit(self, kind: EventKind, step: int) -> None:
        event = AskEvent(kind, self.request, step, self._since)
        if self.on_event is not None:
            self.on_event(event)
