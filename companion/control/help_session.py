"""The session's side of asking for help: what the vehicle does while it asks, and who is told.

:class:`~companion.control.ask.HelpAsker` decides, step by step, whether the policy flies, the
vehicle holds and asks, or it lands because nobody answered. This module carries that out on the
vehicle and tells everyone who should know: the vehicle holds where the request was raised (a
position setpoint, so it does not drift while the person looks), lands in its own mode when the
request goes unanswered, sends each request as a STATUSTEXT (a ground station shows it), tells
the human input (a console shows the request, a synthetic pilot answers it) and an optional
watcher. A person who watches only when asked is away between requests: their input is neutral.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

from companion.control.arbiter import Phase
from companion.control.ask import AskAction, AskEvent, AskSummary, HelpAsker
from companion.control.link_port import HOLD, LinkPort
from companion.errors import ColError
from companion.inputs.base import HumanCommand, HumanInput
from companion.learning.dataset import HumanDataset
from companion.learning.ensemble import EnsembleSnapshot
from companion.learning.snapshot import PolicySnapshot
from companion.msg.snapshot import VehicleSnapshot

log = logging.getLogger(__name__)


class HelpSession:
    """Asking for help on one vehicle, episode by episode (module docstring)."""

    def __init__(self, asker: HelpAsker, human: HumanInput, port: LinkPort, period_s: float,
                 on_event: Callable[[AskEvent], None] | None = None) -> None:
        self.asker, self.human, self.port, self.period_s = asker, human, port, period_s
        self.on_event = on_event
        self.summary: AskSummary | None = None
        self._hold_ned: tuple[float, float, float, float] | None = None
        self._landing = False
        asker.on_event = self._on_ask_event

    def begin(self, episode: int, policy: PolicySnapshot | None, dataset: HumanDataset | None) -> None:
        """New episode: recalibrate the threshold on the dataset as it is now."""
        self._hold_ned, self._landing, self.summary = None, False, None
        self.asker.begin_episode(episode)
        if isinstance(policy, EnsembleSnapshot) and dataset is not None and len(dataset):
            self.asker.calibrate(policy.scores(dataset.view().obs))
        log.info("episode %d: asking for help above disagreement %.4g", episode, self.asker.threshold)

    def end(self, steps: int) -> list[str]:
        """The episode is over: its summary kept for the record; notes for it."""
        self.summary = self.asker.end_episode(steps)
        return ["a request for help went unanswered: landed where it was"] if self.summary.unanswered else []

    def read_human(self, phase: Phase, obs: Any) -> HumanCommand:
        """The person's input; one who watches only when asked is away between requests."""
        if phase is Phase.INTERVENTION and self.human.robot_gated and not self.asker.wants_person:
            return HumanCommand.neutral()
        return self.human.read(obs)

    def action(self, phase: Phase, step: int, score: float, human: HumanCommand) -> AskAction:
        """What this step does: the policy (or person) flies, or the vehicle holds or lands."""
        if phase is not Phase.INTERVENTION:
            return AskAction.POLICY
        return self.asker.step(step, score, human.override_held)

    def carry_out(self, action: AskAction, snap: VehicleSnapshot) -> None:
        """Hold where the request was raised (HOLD), or land (LAND)."""
        if action is AskAction.HOLD:
            if self._hold_ned is None:
                n, e, d = (float(v) for v in snap.position_ned_m)
                self._hold_ned = (n, e, d, float(snap.attitude_rad[2]))
            self.port.send_position(*self._hold_ned)
            return
        if not self._landing:
            self._landing = True
            try:
                self.port.link.land()
            except ColError as exc:
                log.error("could not command the landing: %s; holding", exc)
        self.port.send(HOLD)  # answers the lockstep frame; the vehicle lands in its own mode

    def release_hold(self) -> bool:
        """A step flies again after a hold: True once (the limiter then starts afresh)."""
        released, self._hold_ned = self._hold_ned is not None, None
        return released

    def supervised_steps(self, phase: Phase, steps: int) -> int | None:
        """Steps the person had to watch, when only the requests engaged them (else None)."""
        if phase is Phase.INTERVENTION and self.summary is not None and self.human.robot_gated:
            return self.summary.engaged_steps
        return None

    def _on_ask_event(self, event: AskEvent) -> None:
        req = event.request
        if self.on_event is not None:
            self.on_event(event)
        if event.kind == "request" and req is not None:
            log.warning("asking for help (request %d, step %d): disagreement %.4g above %.4g; holding",
                        req.number, event.step, req.score, req.threshold)
            self._statustext(req.text())
            self.human.on_request(req)
            return
        if event.kind == "unanswered":
            log.warning("no one answered request %d within %.0f s: landing", req.number if req else 0,
                        event.waited_steps * self.period_s)
            self._statustext("COL: no answer, landing")
        else:
            log.info("request %s %s at step %d after %d steps", req.number if req else "-",
                     event.kind.replace("_", " "), event.step, event.waited_steps)
        if event.kind != "handed_back":
            self.human.on_request(None)

    def _statustext(self, text: str) -> None:
        try:
            self.port.link.send_statustext(text)
        except ColError as exc:
            log.error("could not send STATUSTEXT %r: %s", text, exc)
