"""The one overridable seam for human input: ``HumanInput.read(obs) -> HumanCommand``.

Every source (a person with a gamepad, a ground station's joystick, a synthetic pilot) answers
the same question each control tick: what would the person command now, and are they holding
the override trigger? The arbiter decides what to do with the answer.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import TYPE_CHECKING

from companion.commands import JoystickCommand

if TYPE_CHECKING:
    from companion.vision.observation import Observation


@dataclass(frozen=True)
class HumanCommand:
    """The person's sticks and whether they hold the override (take-over) trigger.

    ``hold``: the source can no longer vouch for the sticks (a console's page lost its link
    while the person was flying): while the person is in charge the vehicle holds position and
    nothing is recorded; the policy does not take over because of it.
    """

    command: JoystickCommand
    override_held: bool
    hold: bool = False

    def __post_init__(self) -> None:
        if not isinstance(self.command, JoystickCommand):
            raise TypeError(f"HumanCommand.command must be a JoystickCommand, got {self.command!r}")
        if not isinstance(self.override_held, bool):
            raise TypeError(
                f"HumanCommand.override_held must be a bool, got {self.override_held!r}"
            )
        if not isinstance(self.hold, bool):
            raise TypeError(f"HumanCommand.hold must be a bool, got {self.hold!r}")

    @classmethod
    def neutral(cls) -> HumanCommand:
        """Sticks centred, trigger released: what a silent source means."""
        return cls(JoystickCommand.neutral(), override_held=False)


class HumanInput(ABC):
    """A source of human commands, read once per control tick from the control loop."""

    @abstractmethod
    def read(self, obs: Observation) -> HumanCommand:
        """The person's command for this tick, given what they can see."""

    def reset(self) -> None:
        """Start of an episode: forget anything remembered from the last one."""
        return None  # default: nothing to forget

    def close(self) -> None:
        """Release devices; reading after close is an error of the caller."""
        return None  # default: nothing held
