"""The one overridable seam for human input: ``HumanInput.read(obs) -> HumanCommand``.

Every source (a person with a gamepad, a ground station's joystick, a synthetic pilot) answers
the same question each control tick: what would the person command now, and are they holding
the override trigger? The arbiter decides what to do with the answer.
"""

from __future__ import annotations

import threading
import time
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from companion.msg.command import JoystickCommand

if TYPE_CHECKING:
    from companion.config import PilotConfig
    from companion.msg.observation import Observation


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


@dataclass(frozen=True)
class HelpRequest:
    """The companion asks the person to take over: its policy is unsure here and holds.

    ``number`` counts the requests of a session (from 1); ``score`` is the ensemble's
    disagreement that crossed ``threshold`` at control step ``step`` of ``episode``.
    """

    number: int
    episode: int
    step: int
    score: float
    threshold: float

    def text(self) -> str:
        """What a ground station shows (STATUSTEXT holds 50 characters)."""
        return f"COL: unsure, holding - take over ({self.number})"


class HumanInput(ABC):
    """A source of human commands, read once per control tick from the control loop."""

    robot_gated: bool = False
    """True for a person who watches only when asked: while the companion asks for help
    (``[companion.ask]``), :meth:`read` is called only during a request and while the person
    holds the override; otherwise they count as away (neutral, no override). A person at a
    joystick (False) is read every tick and may take over at any time, asked or not."""

    @abstractmethod
    def read(self, obs: Observation) -> HumanCommand:
        """The person's command for this tick, given what they can see."""

    def reset(self) -> None:
        """Start of an episode: forget anything remembered from the last one."""
        return None  # default: nothing to forget

    def on_request(self, request: HelpRequest | None) -> None:
        """A request for help began (``request``) or ended (None: answered, given up, or the
        episode ended). Default: nothing (a person learns of it from the ground station)."""
        return None

    def close(self) -> None:
        """Release devices; reading after close is an error of the caller."""
        return None  # default: nothing held


class FedInput(HumanInput):
    """A person's input another thread feeds (a link's, the console's server) and the control
    loop reads: the latest command and when it came (``clock``), under one lock. It counts as
    the person's only while it is at most ``manual_timeout_s`` old."""

    def __init__(self, cfg: PilotConfig, clock: Callable[[], float] = time.monotonic) -> None:
        self.cfg = cfg
        self._clock = clock
        self._lock = threading.Lock()
        self._latest = HumanCommand.neutral()
        self._received_s: float | None = None

    def _received_lately(self) -> bool:
        """Whether a command came within ``manual_timeout_s`` (called with the lock held)."""
        received = self._received_s
        return received is not None and self._clock() - received <= self.cfg.manual_timeout_s
