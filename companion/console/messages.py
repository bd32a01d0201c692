"""What a page may send up the socket, checked before anything acts on it.

Every refusal is a :class:`Refused` with a reason meant for the person (it goes back to the
page as an ``error``) and for the log. Sticks are refused, not repaired: a gamepad that reports
NaN or 1e308 is broken, and a repaired value would fly the vehicle and be recorded as if the
person had meant it. A refused input message never reaches :class:`BrowserInput`, so the
page's last good input ages out and the vehicle holds (``manual_timeout_s``).
"""

from __future__ import annotations

import json
import logging
import math
from dataclasses import dataclass, field
from typing import Any

MAX_TEXT_CHARS = 8192  # an input or a command is a few hundred characters
MAX_AXES, MAX_BUTTONS = 16, 32
STICK_TOLERANCE = 1e-6  # a pad reporting 1.0000001 is full deflection, not a fault
COMMANDS = ("start", "go", "auto", "pause", "resume", "next", "stop", "hand_back", "discard_last", "questionnaire")
ROLES = ("pilot", "watch")


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
    """An ``input`` message with sticks in [-1, 1] and buttons in [0, 1], all finite."""
    axes = _values(message, "axes", MAX_AXES, -1.0, 1.0)
    buttons = _values(message, "buttons", MAX_BUTTONS, 0.0, 1.0)
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
class RefusalLog:
    """Logs every refused message with its reason; a run of identical reasons (a broken pad
    at 30 messages/s) is logged once, then counted, and the count logged when it ends."""

    page: str
    logger: logging.Logger
    last: str | None = None
    repeats: int = 0
    total: int = field(default=0)

    def refused(self, reason: str) -> None:
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
