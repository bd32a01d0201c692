"""The SITL's clocks: real time with a speed factor, and lockstep with the companion.

The frame is the unit of both: ``frame_steps`` FDM steps, then the frame's image, telemetry
and SYSTEM_TIME marker (sitl/server.py). Real time paces the steps to the wall clock
(:class:`Pacer`); lockstep waits after each frame for the answer to its marker, and falls back
to real-time pacing while nobody answers (:class:`ClockStats`), so ground stations and MAVSDK
can connect and a vanished companion never hangs it.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

from sitl.config import SitlConfig

DETACH_AFTER_TIMEOUTS = 3  # unanswered lockstep frames in a row before pacing in real time again
MAX_LAG_S = 0.5  # real time this far behind (a debugger, a loaded machine): continue from now


def frame_steps(cfg: SitlConfig) -> int:
    """FDM steps in one agent (camera) frame: 12 at 126 Hz and 10.5 Hz."""
    return max(1, int(round(cfg.clock.fdm_rate_hz / cfg.clock.frame_rate_hz)))


class Pacer:
    """Real time: when the wall clock should reach a simulation time, at ``speed`` simulation
    seconds per wall second, from the last :meth:`restart`."""

    def __init__(self, speed: float) -> None:
        self.speed = speed
        self._wall0 = time.monotonic()
        self._sim0 = 0.0

    def restart(self, sim_s: float) -> None:
        """Simulation time ``sim_s`` is now."""
        self._wall0, self._sim0 = time.monotonic(), sim_s

    def target(self, sim_s: float) -> float:
        """The wall time (``time.monotonic``) at which ``sim_s`` is due; after falling more than
        0.5 s behind it continues from now instead of bursting to catch up."""
        target = self._wall0 + (sim_s - self._sim0) / self.speed
        now = time.monotonic()
        if now - target > MAX_LAG_S:
            self._wall0, self._sim0 = now, sim_s
            target = now
        return target


@dataclass
class ClockStats:
    """The frames run and how lockstep's were answered; ``attached`` while a client drives
    the clock (each frame then waits for its answer)."""

    frames: int = 0
    answered: int = 0
    timeouts: int = 0
    attached: bool = False
    timeouts_in_row: int = 0
    extra: dict = field(default_factory=dict)

    def attach(self) -> None:
        """A client answered (or reset an episode): from now on each frame waits for it."""
        self.attached = True
        self.timeouts_in_row = 0

    def frame_ended(self, answered: bool) -> bool:
        """Count an attached lockstep frame; True when it was the last unanswered one allowed
        and the clock detached (it paces itself in real time until the client answers)."""
        if answered:
            self.answered += 1
            self.timeouts_in_row = 0
            return False
        self.timeouts += 1
        self.timeouts_in_row += 1
        if self.timeouts_in_row >= DETACH_AFTER_TIMEOUTS:
            self.attached = False
            return True
        return False
