"""A ground station's joystick, as MAVLink MANUAL_CONTROL messages.

Axes as MAVLink defines them: ``x`` pitch (forward +1000), ``y`` roll (right +1000), ``r`` yaw
(clockwise +1000), each in [-1000, 1000]; ``z`` thrust, which QGroundControl and MAVProxy send
for a multirotor in [0, 1000] with 500 as centre (``manual_throttle_range``). A value of
INT16_MAX means "axis not present" and reads as centred. One bit of ``buttons`` (bits 0-15) or
``buttons2`` (bits 16-31) is the override trigger. The link's thread calls :meth:`feed`; the
control loop calls :meth:`read`. A message older than ``manual_timeout_s`` means the stick is
gone: neutral command, no override.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from companion.config import PilotConfig
from companion.inputs.base import FedInput, HumanCommand
from companion.msg.command import JoystickCommand

if TYPE_CHECKING:
    from companion.msg.observation import Observation

log = logging.getLogger(__name__)

AXIS_ABSENT = 32767  # INT16_MAX: MAVLink's "this axis is not provided"


@dataclass(frozen=True)
class ManualControlCounts:
    """What :class:`ManualControlInput` has received and repaired so far."""

    messages: int = 0
    clamped_axes: int = 0
    invalid_axes: int = 0
    stale_reads: int = 0


def _axis(raw: Any, lo: float, hi: float) -> tuple[float, str]:
    """One raw axis to [-1, 1] given the raw values for -1 and +1; and what was repaired."""
    if raw is None:
        return 0.0, "absent"
    try:
        value = float(raw)
    except (TypeError, ValueError):
        return 0.0, "invalid"
    if value == AXIS_ABSENT:
        return 0.0, "absent"
    if not math.isfinite(value):
        return 0.0, "invalid"
    unit = 2.0 * (value - lo) / (hi - lo) - 1.0
    if unit > 1.0 or unit < -1.0:
        return max(-1.0, min(1.0, unit)), "clamped"
    return unit, ""


def button_held(fields: Mapping[str, Any], bit: int) -> bool:
    """Whether button ``bit`` (0-31) is pressed; bits 16-31 live in ``buttons2``."""
    word = fields.get("buttons", 0) if bit < 16 else fields.get("buttons2", 0)
    try:
        return bool((int(word or 0) >> (bit % 16)) & 1)
    except (TypeError, ValueError):
        return False


class ManualControlInput(FedInput):
    """The latest MANUAL_CONTROL as a HumanCommand; thread-safe between feed and read."""

    def __init__(self, cfg: PilotConfig, clock: Callable[[], float] = time.monotonic) -> None:
        super().__init__(cfg, clock)
        self._stale_warned = False
        self._counts = ManualControlCounts()

    @property
    def counts(self) -> ManualControlCounts:
        with self._lock:
            return self._counts

    def to_command(self, fields: Mapping[str, Any]) -> tuple[HumanCommand, int, int]:
        """Map one message's fields; also the numbers of clamped and invalid axes."""
        z_lo, z_hi = self.cfg.manual_throttle_range
        raw = {
            "roll": _axis(fields.get("y"), -1000.0, 1000.0),
            "pitch": _axis(fields.get("x"), -1000.0, 1000.0),
            "yaw": _axis(fields.get("r"), -1000.0, 1000.0),
            "throttle": _axis(fields.get("z"), float(z_lo), float(z_hi)),
        }
        cmd = JoystickCommand(**{name: value for name, (value, _) in raw.items()})
        clamped = sum(1 for _, why in raw.values() if why == "clamped")
        invalid = sum(1 for _, why in raw.values() if why == "invalid")
        held = button_held(fields, self.cfg.manual_override_button)
        return HumanCommand(cmd, override_held=held), clamped, invalid

    def feed(self, fields: Mapping[str, Any]) -> None:
        """Take one MANUAL_CONTROL message (its fields by name); called from the link's thread."""
        human, clamped, invalid = self.to_command(fields)
        if clamped or invalid:
            log.warning(
                "MANUAL_CONTROL with %d out-of-range and %d invalid axes (%s); clamped/centred. "
                "Check the ground station's joystick calibration.",
                clamped,
                invalid,
                dict(fields),
            )
        with self._lock:
            self._latest, self._received_s = human, self._clock()
            self._stale_warned = False
            c = self._counts
            self._counts = ManualControlCounts(
                c.messages + 1, c.clamped_axes + clamped, c.invalid_axes + invalid, c.stale_reads
            )

    def read(self, obs: Observation | None = None) -> HumanCommand:
        """The latest command, or neutral without override when it is older than the timeout."""
        with self._lock:
            if self._received_lately():
                return self._latest
            if self._received_s is not None:
                if not self._stale_warned:
                    log.warning(
                        "no MANUAL_CONTROL for more than %.2f s: sticks centred, override "
                        "released. Check the ground station's joystick and link.",
                        self.cfg.manual_timeout_s,
                    )
                    self._stale_warned = True
                c = self._counts
                self._counts = ManualControlCounts(
                    c.messages, c.clamped_axes, c.invalid_axes, c.stale_reads + 1
                )
            return HumanCommand.neutral()
