"""A person's gamepad (or keyboard) in the console's web page, sent over its WebSocket.

The sibling of :mod:`companion.inputs.manual_control`: the server's event loop calls
:meth:`BrowserInput.feed` with each message of the page, the control loop calls :meth:`read`.
The page sends the browser's Gamepad API state in its "standard" layout (an Xbox pad): axes
0/1 left stick x/y, 2/3 right stick x/y (y is +1 down), button 7 the right trigger (0..1).
As in the paper: left stick throttle/yaw, right stick pitch/roll, right trigger = override.
Deadband and expo are applied later by the command mapper, as for every source; what is
recorded is the stick itself.

A state that is not a whole pad (fewer than the 4 axes and 8 buttons the mapping reads) is
refused (:func:`pad_shape_error`), never read as centred sticks: a pad that reports 2 axes is
not a person holding the right stick still.

Safety: when the page falls silent (its socket closes, the pilot gives up the role, its input is
refused, or no message for ``manual_timeout_s``) while the person is flying, :meth:`read` says
``hold``: the vehicle hovers, nothing is recorded, and if the override was held the hold stays
latched until the person takes the sticks again (trigger held) or hands back explicitly
(:meth:`hand_back`): the policy never takes over silently. The status names the reason
(:meth:`BrowserInput.why_holding`).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from companion.commands import sanitize
from companion.config import PilotConfig
from companion.inputs.base import FedInput, HumanCommand
from companion.msg.command import JoystickCommand

if TYPE_CHECKING:
    from companion.msg.observation import Observation

log = logging.getLogger(__name__)

LEFT_X, LEFT_Y, RIGHT_X, RIGHT_Y = 0, 1, 2, 3  # Gamepad API "standard" mapping
RIGHT_TRIGGER = 7
AXES_NEEDED = RIGHT_Y + 1  # what the mapping reads: both sticks ...
BUTTONS_NEEDED = RIGHT_TRIGGER + 1  # ... and the right trigger
NO_PAGE = "no pilot page is connected"
LINK_LOST = "the console's page lost its link"


@dataclass(frozen=True)
class BrowserStatus:
    """What the console shows about the person's input."""

    connected: bool
    fresh: bool
    holding: bool
    hold_reason: str | None  # why a latched hold holds (until the trigger or a hand-back)
    lost_reason: str | None  # why the person's input is missing now (None while it is fresh)
    messages: int
    repaired_axes: int
    last_seq: int | None
    command: HumanCommand


def _number(value: Any) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        return math.nan
    return x


def pad_shape_error(axes: int, buttons: int) -> str | None:
    """Why a pad state with this many axes and buttons cannot fly (None: it can). The mapping
    reads 4 axes and button 7; a shorter state is not centred sticks and a released trigger,
    it is a pad the console cannot read (another layout, a broken driver, a forged page)."""
    if axes < AXES_NEEDED:
        return (f"this gamepad reports {axes} axes; the console needs {AXES_NEEDED} (both sticks, the "
                "Gamepad API's standard layout of an Xbox pad): its sticks are refused, not read as centred")
    if buttons < BUTTONS_NEEDED:
        return (f"this gamepad reports {buttons} buttons; the console needs {BUTTONS_NEEDED} (button "
                f"{RIGHT_TRIGGER} is the right trigger, the override): its state is refused")
    return None


def command_from_gamepad(axes: Sequence[Any], buttons: Sequence[Any],
                         trigger_threshold: float) -> tuple[HumanCommand, int]:
    """The Gamepad API's standard layout as a HumanCommand, and how many axes were repaired
    (non-finite -> centred, out of range -> clamped). ValueError for a state with too few axes
    or buttons (:func:`pad_shape_error`)."""
    error = pad_shape_error(len(axes), len(buttons))
    if error is not None:
        raise ValueError(error)
    # 0.0 - y, not -y: a centred stick is +0.0 (the dataset would say "-0")
    raw = [_number(axes[RIGHT_X]), 0.0 - _number(axes[RIGHT_Y]), _number(axes[LEFT_X]), 0.0 - _number(axes[LEFT_Y])]
    cmd, issues = sanitize(raw)
    trigger = _number(buttons[RIGHT_TRIGGER])
    held = math.isfinite(trigger) and trigger > trigger_threshold
    return HumanCommand(cmd, override_held=held), issues.non_finite + issues.clamped


class BrowserInput(FedInput):
    """The page's latest sticks; thread-safe between the server (feed) and control (read)."""

    def __init__(self, cfg: PilotConfig, clock: Callable[[], float] = time.monotonic) -> None:
        super().__init__(cfg, clock)
        self._connected = False
        self._gone: str | None = NO_PAGE  # why no page is connected
        self._refused: str | None = None  # why the page's latest input was refused (until a good one)
        self._latched: str | None = None  # why the vehicle holds until the person acts
        self._messages = 0
        self._repaired = 0
        self._last_seq: int | None = None
        self.last_page_ms: float | None = None  # the page's clock in the latest message

    def connected(self) -> None:
        """A page opened its socket (it is the pilot's)."""
        with self._lock:
            self._connected, self._gone, self._refused = True, None, None

    def disconnected(self, why: str = LINK_LOST) -> None:
        """The pilot's page left (``why``: its link dropped, the pilot gave up the role): from now
        on :meth:`read` sees silence, and the status says why."""
        with self._lock:
            self._connected = False
            self._received_s = None
            self._gone, self._refused = why, None

    def refused(self, reason: str) -> None:
        """The pilot's page sent an input the console refused (not fed): if its last good input
        ages out, the hold says why."""
        with self._lock:
            self._refused = reason

    def feed(self, message: Mapping[str, Any]) -> None:
        """One ``{"type": "input", "axes": [...], "buttons": [...], "seq": n, "t": ms}`` message;
        ValueError (nothing fed) for one that is not a whole pad's state."""
        axes, buttons = message.get("axes"), message.get("buttons")
        if not isinstance(axes, Sequence) or not isinstance(buttons, Sequence) or isinstance(axes, str) \
                or isinstance(buttons, str):
            raise ValueError("an input message needs lists 'axes' and 'buttons'")
        human, repaired = command_from_gamepad(axes, buttons, self.cfg.gamepad_trigger_threshold)
        seq = message.get("seq")
        with self._lock:
            self._latest, self._received_s, self._connected = human, self._clock(), True
            self._gone = self._refused = None
            self._messages += 1
            self._repaired += repaired
            self._last_seq = int(seq) if isinstance(seq, int) else self._last_seq
            self.last_page_ms = _number(message.get("t")) if message.get("t") is not None else None

    def hand_back(self) -> None:
        """The person lets the policy fly again after a hold (a button in the page)."""
        with self._lock:
            if self._latched is not None:
                log.warning("the person handed control back to the policy after: %s", self._latched)
            self._latched = None

    def reset(self) -> None:
        """A new episode starts from the person's current sticks, without a latched hold."""
        with self._lock:
            self._latched = None

    def _fresh(self) -> bool:
        return self._connected and self._received_lately()

    def _lost_reason(self) -> str | None:
        """Why the person's input is missing now (None while it is fresh)."""
        if self._fresh():
            return None
        if not self._connected:
            return self._gone or NO_PAGE
        if self._refused is not None:
            return f"the pilot's input is refused ({self._refused})"
        if self._received_s is None:
            return "the pilot's page has sent no input yet"
        return f"the pilot's page sent no input for more than {self.cfg.manual_timeout_s:g} s"

    def why_holding(self) -> str | None:
        """Why the vehicle would hold now on the person's account: a latched hold's reason, or
        why the input is missing; None while the input is fresh and nothing is latched."""
        with self._lock:
            return self._latched or self._lost_reason()

    def read(self, obs: Observation | None = None) -> HumanCommand:
        """The page's sticks; ``hold`` while it is silent or a lost link's hold is latched."""
        with self._lock:
            if not self._fresh():
                if self._latest.override_held and self._latched is None:
                    self._latched = f"{self._lost_reason()} while the person held the override"
                    log.warning("%s: holding position; the policy does not take over", self._latched)
                return HumanCommand(JoystickCommand.neutral(), override_held=self._latched is not None,
                                    hold=True)
            if self._latched is not None:
                if not self._latest.override_held:
                    return HumanCommand(JoystickCommand.neutral(), override_held=True, hold=True)
                log.warning("the person has the sticks again after: %s", self._latched)
                self._latched = None
            return self._latest

    def status(self) -> BrowserStatus:
        with self._lock:
            return BrowserStatus(self._connected, self._fresh(), self._latched is not None or not self._fresh(),
                                 self._latched, self._lost_reason(), self._messages, self._repaired,
                                 self._last_seq, self._latest)
