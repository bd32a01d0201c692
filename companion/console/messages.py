"""What a page may send up the socket, checked before anything acts on it.

Every refusal is a :class:`Refused` with a reason meant for the person (it goes back to the
page as an ``error``) and for the log. Sticks are refused, not repaired: a gamepad that reports
NaN or 1e308 is broken, and a repaired value would fly the vehicle and be recorded as if the
person had meant it. A state without the 4 axes and 8 buttons the mapping reads is refused
too (:func:`~companion.inputs.browser.pad_shape_error`), never read as centred sticks. A
refused input message never reaches :class:`BrowserInput`, so the page's last good input ages
out and the vehicle holds (``manual_timeout_s``).

Every refusal is counted (:class:`RefusalLog`) and the page is told with the running count:
the first of a run at once, then at most every :data:`REFUSAL_SEND_INTERVAL_S` per reason (a
broken pad sends 30 messages a second), and a count not yet sent goes out when that interval
ends, so no refusal is silent.
"""

from __future__ import annotations

import json
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from companion.inputs.browser import pad_shape_error

MAX_TEXT_CHARS = 8192  # an input or a command is a few hundred characters
MAX_AXES, MAX_BUTTONS = 16, 32
STICK_TOLERANCE = 1e-6  # a pad reporting 1.0000001 is full deflection, not a fault
COMMANDS = ("start", "go", "auto", "pause", "resume", "next", "stop", "hand_back", "discard_last", "questionnaire")
ROLES = ("pilot", "watch")
REFUSAL_SEND_INTERVAL_S = 0.5  # the page is told of one reason's refusals at most this often ...
MAX_REASONS_COUNTED = 64  # ... and the counts of this many reasons are kept per page


class Refused(ValueError):
    """A message the console will not act on, and why (for the page and the log)."""


def parse(text: str) -> dict[str, Any]:
    """One text message as a JSON object; Refused for anything else (never another exception)."""
    if len(text) > MAX_TEXT_CHARS:
        raise Refused(f"a message of {len(text)} characters; the console takes at most {MAX_TEXT_CHARS}")
    try:
        message = json.loads(text)
    except RecursionError:
        raise Refused("a message nested too deeply to read") from None
    except ValueError as exc:
        raise Refused(f"not JSON: {exc}") from None
    if not isinstance(message, dict):
        raise Refused(f"a message is a JSON object, got {type(message).__name__}")
    return message


def _values(message: dict[str, Any], key: str, most: int, low: float, high: float) -> list[float]:
    values = message.get(key)
    if not isinstance(values, list) or len(values) > most:
        raise Refused(f"input needs '{key}' as a list of at most {most} numbers")
    for i, v in enumerate(values):
        if isinstance(v, bool) or not isinstance(v, int | float):
            shown = "null (NaN or Infinity in the page)" if v is None else repr(v)[:40]
            raise Refused(f"input refused: {key}[{i}] is {shown}, not a number")
        if not math.isfinite(v) or not low - STICK_TOLERANCE <= v <= high + STICK_TOLERANCE:
            raise Refused(f"input refused: {key}[{i}] = {v!r} is outside [{low:g}, {high:g}]")
    return [float(v) for v in values]


def check_input(message: dict[str, Any]) -> dict[str, Any]:
    """An ``input`` message with sticks in [-1, 1] and buttons in [0, 1], all finite, and at
    least the axes and buttons the mapping reads (4 axes; button 7, the right trigger)."""
    axes = _values(message, "axes", MAX_AXES, -1.0, 1.0)
    buttons = _values(message, "buttons", MAX_BUTTONS, 0.0, 1.0)
    shape = pad_shape_error(len(axes), len(buttons))
    if shape is not None:
        raise Refused(shape)
    seq, t = message.get("seq"), message.get("t")
    return {"type": "input", "axes": axes, "buttons": buttons,
            "seq": seq if isinstance(seq, int) and not isinstance(seq, bool) else None,
            "t": t if isinstance(t, int | float) and not isinstance(t, bool) and math.isfinite(t) else None}


def command_name(message: dict[str, Any]) -> str:
    name = message.get("name")
    if name not in COMMANDS:
        raise Refused(f"unknown command {str(name)[:40]!r}; use one of {', '.join(COMMANDS)}")
    return str(name)


def role_wanted(message: dict[str, Any]) -> str:
    want = message.get("want")
    if want not in ROLES:
        raise Refused(f"a role message wants 'pilot' or 'watch', got {str(want)[:40]!r}")
    return str(want)


def whole_number(value: Any, what: str, low: int, high: int) -> int:
    """``value`` as a whole number in [low, high]: 2.5 and "2" are refused, not rounded."""
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise Refused(f"{what} must be a whole number from {low} to {high}, got {str(value)[:40]!r}")
    return value


@dataclass
class _Told:
    """One reason's refusals from one page: how many, and how many the page was told of, when."""

    count: int = 0
    told: int = 0
    told_s: float = -math.inf


@dataclass
class RefusalLog:
    """Logs every refused message with its reason; a run of identical reasons (a broken pad
    at 30 messages/s) is logged once, then counted, and the count logged when it ends.

    It also decides when the page is told (:meth:`refused`, :meth:`unsent`): every refusal is
    counted per reason; the first after an accepted message (:meth:`accepted`) or after another
    reason is told at once, the rest of a run at most every ``interval_s``, with the count."""

    page: str
    logger: logging.Logger
    last: str | None = None
    repeats: int = 0
    total: int = field(default=0)
    clock: Callable[[], float] = time.monotonic
    interval_s: float = REFUSAL_SEND_INTERVAL_S
    counts: dict[str, _Told] = field(default_factory=dict)
    run: str | None = None  # the reason of the current run of refusals (None: the next is told at once)

    def refused(self, reason: str) -> bool:
        """Count (and log) one refusal; True when the page is to be told now (:meth:`count`)."""
        self._log(reason)
        told = self.counts.pop(reason, None) or _Told()
        self.counts[reason] = told  # the newest reason last: the oldest is forgotten first
        while len(self.counts) > MAX_REASONS_COUNTED:
            del self.counts[next(iter(self.counts))]
        told.count += 1
        now = self.clock()
        if reason != self.run or now - told.told_s >= self.interval_s:
            self.run = reason
            told.told, told.told_s = told.count, now
            return True
        return False

    def count(self, reason: str) -> int:
        """How many times this page's messages were refused for ``reason`` (while remembered)."""
        told = self.counts.get(reason)
        return told.count if told is not None else 0

    def accepted(self) -> None:
        """A message was acted on: the next refusal is told at once, whatever its reason."""
        self.run = None

    def unsent(self) -> list[tuple[str, int]]:
        """The reasons whose latest count the page was not told yet, with that count (now told)."""
        now, out = self.clock(), []
        for reason, told in self.counts.items():
            if told.count > told.told:
                told.told, told.told_s = told.count, now
                out.append((reason, told.count))
        return out

    def _log(self, reason: str) -> None:
        self.total += 1
        if reason == self.last:
            self.repeats += 1
            if self.repeats % 100 == 0:
                self.logger.warning("page %s: the same refusal %d more times: %s", self.page, self.repeats, reason)
            return
        self.flush()
        self.last = reason
        self.logger.warning("page %s: refused a message: %s", self.page, reason)

    def flush(self) -> None:
        """Log how often the last reason repeated (on a new reason or when the page leaves)."""
        if self.repeats % 100:
            self.logger.warning("page %s: the same refusal %d times in all: %s", self.page, self.repeats, self.last)
        self.last, self.repeats = None, 0
