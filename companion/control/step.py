"""One control step's decision on one vehicle, the pipeline every step of the session flies.

observation -> the person (or, when asking for help, only when asked) and the policy -> the
arbiter (asking's hold and landing inside it) -> [demonstration noise, when on] -> mapper ->
limiter -> touchdown assist -> the setpoint to send, plus the sample to record (always the
person's own command). The touchdown assist comes after the limiter on
purpose: a land detector needs a descent the limiter's rate limit would spread over seconds; it
only ever asks for a descent within the commands' limits (companion/control/touchdown.py,
tests/control/test_touchdown.py).

Nothing here talks to the vehicle: the driver sends the setpoint, or has asking carry out its
hold or landing (companion/control/help_session.py), and appends the sample to the dataset.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from companion.commands import CommandMapper
from companion.control.arbiter import Arbiter, Decision, Phase
from companion.control.ask import AskAction
from companion.control.demo_noise import DemoNoise
from companion.control.help_session import HelpSession
from companion.control.link_port import HOLD
from companion.control.safety import SetpointLimiter
from companion.control.touchdown import VehicleTouchdown
from companion.inputs.base import HumanCommand, HumanInput
from companion.learning.ensemble import disagreement
from companion.learning.snapshot import PolicySnapshot
from companion.msg.command import JoystickCommand
from companion.msg.observation import Observation
from companion.msg.sample import Sample, Source
from companion.msg.setpoint import VelocitySetpoint
from companion.msg.snapshot import VehicleSnapshot

log = logging.getLogger(__name__)


class PolicyRunner(Protocol):
    """What the session needs of a learner runner (BudgetedLearner, LearnerThread)."""

    @property
    def latest_snapshot(self) -> PolicySnapshot: ...

    @property
    def error(self) -> BaseException | None: ...

    def on_control_step(self, tick_start_s: float | None = None) -> PolicySnapshot: ...


class StepParts(Protocol):
    """What a step needs of the session's parts (read at each step: a run may swap them)."""

    @property
    def mapper(self) -> CommandMapper: ...

    @property
    def human(self) -> HumanInput: ...

    @property
    def limiter(self) -> SetpointLimiter: ...

    @property
    def runner(self) -> PolicyRunner | None: ...


@dataclass(frozen=True)
class StepChoice:
    """What one step decided: the person's input, the arbiter's decision, what asking for help
    wants, the policy's version and disagreement (NaN: a single network), and the setpoint to
    send (None: asking holds or lands the vehicle instead)."""

    human: HumanCommand
    decision: Decision
    action: AskAction
    version: int | None
    score: float
    setpoint: VelocitySetpoint | None

    @property
    def shown(self) -> VelocitySetpoint:
        """What a watcher is shown: the setpoint sent, or the hold while asking holds or lands."""
        return HOLD if self.setpoint is None else self.setpoint

    def sample(self, episode: int, step: int, t0_ms: int, obs: Observation, vector: np.ndarray) -> Sample | None:
        """The person's sample of this step, if the arbiter records it (``t0_ms``: the episode's start)."""
        if not self.decision.record:
            return None
        source = Source.DEMONSTRATION if self.decision.tag == "demonstration" else Source.INTERVENTION
        return Sample(episode, step, (obs.time_boot_ms - t0_ms) / 1000.0, source, vector, self.decision.command.to_array())


class StepPipeline:
    """The step decision on one vehicle, episode by episode (module docstring)."""

    def __init__(self, parts: StepParts, period_s: float, help: HelpSession | None, touchdown: VehicleTouchdown,
                 noise: DemoNoise | None = None) -> None:
        self.p, self.period_s, self.help, self.touchdown = parts, period_s, help, touchdown
        self.noise = noise
        """Stick noise on the demonstration steps the vehicle flies (control/demo_noise.py); None: none."""
        self.arbiter = Arbiter()
        self._warned_learner = False

    def reset(self, episode: int = 0) -> None:
        """A new episode: the arbiter's count, the person's input, the limiter, the assist and the
        demonstration noise's stream afresh."""
        if self.noise is not None:
            self.noise.begin(episode)
        self.arbiter.reset()
        self.p.human.reset()
        self.p.limiter.reset()
        self.touchdown.reset()

    def decide(self, phase: Phase, step: int, obs: Observation, vector: np.ndarray, snap: VehicleSnapshot) -> StepChoice:
        """This step's decision on the observation ``obs`` (``vector``) of the telemetry ``snap``."""
        help = self.help
        human = help.read_human(phase, obs) if help is not None else self.p.human.read(obs)
        policy_cmd, version, score = self.policy_command(vector)
        action = help.action(phase, step, score, human) if help is not None else AskAction.POLICY
        decision = self.arbiter.decide(phase, human, policy_cmd, recordable=not obs.frame_missing, asked=action)
        setpoint = None if decision.source in ("hold", "land") else self.setpoint(self.flown(decision), snap)
        return StepChoice(human, decision, action, version, score, setpoint)

    def flown(self, decision: Decision) -> JoystickCommand:
        """What the vehicle flies: the decision's command, with the noise on a demonstration step
        (the sample keeps the person's own command)."""
        if self.noise is not None and decision.tag == "demonstration":
            return self.noise.flown(decision.command)
        return decision.command

    def policy_command(self, obs_vector: np.ndarray) -> tuple[JoystickCommand, int | None, float]:
        """The policy's command, its version and its disagreement (NaN: a single network)."""
        runner = self.p.runner
        if runner is None:
            return JoystickCommand.neutral(), None, math.nan
        if runner.error is not None and not self._warned_learner:
            self._warned_learner = True
            log.error("learner failed (%s); flying the last good policy", runner.error)
        snap = runner.latest_snapshot
        action, score = disagreement(snap, obs_vector)
        return self.p.mapper.command_from_values(action), snap.version, score

    def setpoint(self, command: JoystickCommand, snap: VehicleSnapshot) -> VelocitySetpoint:
        """The command as the vehicle is sent it: mapped, limited, then the touchdown assist."""
        if self.help is not None and self.help.release_hold():  # rate limits start from what is asked now
            self.p.limiter.reset()
        sp = self.limited(command)
        assist = self.touchdown.assist
        return assist.apply(sp, snap) if assist is not None else sp

    def limited(self, command: JoystickCommand) -> VelocitySetpoint:
        """The command mapped and limited (a caller that chooses every command; a stale step's hold)."""
        return self.p.limiter.apply(self.p.mapper.to_setpoint(command), self.period_s)
