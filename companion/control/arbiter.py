"""Who flies this tick, the person or the policy, and whether the tick is recorded.

The one place where blending happens. The decision takes effect in the same tick as the
input: the step where the override becomes held already uses the person's command. Only the
person's commands are ever recorded, tagged by the session's phase. When the person is in
charge but their input is lost (``HumanCommand.hold``), the vehicle hovers (neutral sticks),
nothing is recorded and the policy does not take over: it flies again only when the person
lets go explicitly. When asking for help (companion/control/ask.py) holds the vehicle where it
asked, or lands it because nobody answered, that overrides both ("hold", "land"): nothing is
recorded, since nobody's command flies.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
from typing import Literal

from companion.control.ask import AskAction
from companion.inputs.base import HumanCommand
from companion.msg.command import JoystickCommand

Source = Literal["human", "policy", "hold", "land"]
ASKED: dict[AskAction, Source] = {AskAction.HOLD: "hold", AskAction.LAND: "land"}
Tag = Literal["demonstration", "intervention"]


class Phase(Enum):
    """The session's phase: who is expected to fly and what is learned from."""

    DEMONSTRATION = "demonstration"
    INTERVENTION = "intervention"
    AUTONOMOUS = "autonomous"


@dataclass(frozen=True)
class Decision:
    """The command to send this tick, whose it is, and how (whether) to record it."""

    command: JoystickCommand
    source: Source
    record: bool
    tag: Tag | None

    def __post_init__(self) -> None:
        if self.source not in ("human", "policy", "hold", "land"):
            raise ValueError(f"Decision.source must be 'human', 'policy', 'hold' or 'land', got {self.source!r}")
        if self.record != (self.tag is not None):
            raise ValueError(
                "a recorded decision needs a tag and an unrecorded one must not have one"
            )
        if self.record and self.source != "human":
            raise ValueError("only the person's commands are recorded, never the policy's")


@dataclass(frozen=True)
class InterventionSummary:
    """An episode's human involvement, for the episode record."""

    steps: int
    human_steps: int
    recorded_steps: int
    interventions: int
    durations_steps: tuple[int, ...]
    """Length of each intervention in control steps (the last may still be running)."""

    def durations_s(self, control_period_s: float) -> tuple[float, ...]:
        return tuple(n * control_period_s for n in self.durations_steps)


class Arbiter:
    """Decides each tick; counts interventions (rising edges of the held override) per episode."""

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        """Start of an episode: clear the counts."""
        self._steps = self._human_steps = self._recorded_steps = 0
        self._durations: list[int] = []
        self._intervening = False

    def decide(self, phase: Phase, human: HumanCommand, policy_cmd: JoystickCommand,
               recordable: bool = True, asked: AskAction = AskAction.POLICY) -> Decision:
        """The person in demonstrations, and in interventions while holding the override.
        ``recordable=False``: the step's observation is not the vehicle's true state (its camera
        frame is missing, companion/control/gaps.py): the same command flies, nothing is recorded.
        ``asked``: what asking for help wants this step; HOLD and LAND override both."""
        decision = self._choose(phase, human, policy_cmd)
        if asked in ASKED:
            decision = Decision(JoystickCommand.neutral(), ASKED[asked], False, None)
        elif decision.record and not recordable:
            decision = Decision(decision.command, decision.source, False, None)
        self._count(phase, human, decision)
        return decision

    @staticmethod
    def _choose(phase: Phase, human: HumanCommand, policy_cmd: JoystickCommand) -> Decision:
        person_in_charge = phase is Phase.DEMONSTRATION or (phase is Phase.INTERVENTION and human.override_held)
        if person_in_charge and human.hold:  # their input is gone: hover, record nothing
            return Decision(JoystickCommand.neutral(), "human", False, None)
        if phase is Phase.DEMONSTRATION:
            return Decision(human.command, "human", True, "demonstration")
        if phase is Phase.INTERVENTION and human.override_held:
            return Decision(human.command, "human", True, "intervention")
        return Decision(policy_cmd, "policy", False, None)

    def _count(self, phase: Phase, human: HumanCommand, decision: Decision) -> None:
        self._steps += 1
        self._human_steps += decision.source == "human"
        self._recorded_steps += decision.record
        intervening = phase is Phase.INTERVENTION and human.override_held
        if intervening and not self._intervening:
            self._durations.append(0)
        if intervening:
            self._durations[-1] += 1
        self._intervening = intervening

    def summary(self) -> InterventionSummary:
        return InterventionSummary(
            steps=self._steps,
            human_steps=self._human_steps,
            recorded_steps=self._recorded_steps,
            interventions=len(self._durations),
            durations_steps=tuple(self._durations),
        )
