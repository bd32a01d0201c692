"""A person's gamepad (or keyboard) in the console's web page, sent over its WebSocket.

The sibling of :mod:`companion.inputs.manual_control`: the server's event loop calls
:meth:`BrowserInput.feed` with each message of the page, the control loop calls :meth:`read`.
The page sends the browser's Gamepad API state in its "standard" layout (an Xbox pad): axes
0/1 left stick x/y, 2/3 right stick x/y (y is +1 down), button 7 the right trigger (0..1).
As in the paper: left stick throttle/yaw, right stick pitch/roll, right trigger = override.
Deadband and expo are applied later by the command mapper, as for every source; what is
recorded is the stick itself.

Safety: when the page falls silent (its socket closes, or no message for
``manual_timeout_s``) while the person is flying, :meth:`read` says ``hold``: the vehicle hovers,
nothing is recorded, and if the override was held the hold stays latched until the person
takes the sticks again (trigger held) or hands back explicitly (:meth:`hand_back`): the policy
never takes over silently.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from companion.commands import JoystickCommand, sanitize
from companion.config import PilotConfig
from companion.inputs.base import HumanCommand, HumanInput

if TYPE_CHECKING:
    from companion.vision.observation import Observation

log = logging.getLogger(__name__)

LEFT_X, LEFT_Y, RIGHT_X, RIGHT_Y = 0, 1, 2, 3  # Gamepad API "standard" mapping
RIGHT_TRIGGER = 7


@dataclass(frozen=True)
class BrowserStatus:
    """What the console shows about the person's input."""

    connected: bool
    fresh: bool
    holding: bool
    hold_reason: str | None
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


def _at(values: Sequence[Any], index: int) -> float:
    return _number(values[index]) if index < len(values) else 0.0


def command_from_gamepad(axes: Sequence[Any], buttons: Sequence[Any],
                         trigger_threshold: float) -> tuple[HumanCommand, int]:
    """The Gamepad API's standard layout as a HumanCommand, and how many axes were repaired
    (non-finite -> centred, out of range -> clamped)."""
    # 0.0 - y, not -y: a centred stick is +0.0 (the dataset would say "-0")
    raw = [_at(axes, RIGHT_X), 0.0 - _at(axes, RIGHT_Y), _at(axes, LEFT_X), 0.0 - _at(axes, LEFT_Y)]
    cmd, issues = sanitize(raw)
    trigger = _at(buttons, RIGHT_TRIGGER)
    held = math.isfinite(trigger) and trigger > trigger_threshold
    return HumanCommand(cmd, override_held=held), issues.non_finite + issues.clamped


class BrowserInput(HumanInput):
    """The page's latest sticks; thread-safe between the server (feed) and control (read)."""

    def __init__(self, cfg: PilotConfig, clock: Callable[[], float] = time.monotonic) -> None:
        self.cfg = cfg
        self._clock = clock
        self._lock = threading.Lock()
        self._latest = HumanCommand.neutral()
        self._received_s: float | None = None
        self._connected = False
        self._latched: str | None = None  # why the vehicle holds until the person acts
        self._messages = 0
        self._repaired = 0
        self._last_seq: int | None = None
        self.last_page_ms: float | None = None  # the page's clock in the latest message

    def connected(self) -> None:
        """A page opened its socket."""
        with self._lock:
            self._connected = True

    def disconnected(self) -> None:
        """The page's socket closed: from now on :meth:`read` sees silence."""
        with self._lock:
            self._connected = False
            self._received_s = None

    def feed(self, message: Mapping[str, Any]) -> None:
        """One ``{"type": "input", "axes": [...], "buttons": [...], "seq": n, "t": ms}`` message."""
        axes, buttons = message.get("axes") or [], message.get("buttons") or []
        if not isinstance(axes, Sequence) or not isinstance(buttons, Sequence):
            raise ValueError("an input message needs lists 'axes' and 'buttons'")
        human, repaired = command_from_gamepad(axes, buttons, self.cfg.gamepad_trigger_threshold)
        seq = message.get("seq")
        with self._lock:
            self._latest, self._received_s, self._connected = human, self._clock(), True
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
        return (self._connected and self._received_s is not None
                and self._clock() - self._received_s <= self.cfg.manual_timeout_s)

    def read(self, obs: Observation | None = None) -> HumanCommand:
        """The page's sticks; ``hold`` while it is silent or a lost link's hold is latched."""
        with self._lock:
            if not self._fresh():
                if self._latest.override_held and self._latched is None:
                    self._latched = "the console's page lost its link while the person held the override"
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
                                 self._latched, self._messages, self._repaired, self._last_seq, self._latest)
