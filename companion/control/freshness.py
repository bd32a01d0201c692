"""No control step without fresh telemetry: the rule that keeps every recorded sample true.

An observation is made of the vehicle's position and velocity (LOCAL_POSITION_NED) and its
attitude and rates (ATTITUDE). A step may use them only when each is newer than the previous
step's, by the vehicle's own stamp of that message (``time_boot_ms``): not by when it arrived
(a stalled link delivers old news late) and not by the newest stamp of any message (a SYSTEM_TIME
or a HEARTBEAT says nothing of the position). A frozen or starved autopilot, or a link that
stalls, stops these stamps; the step then holds and records nothing (companion/control/gaps.py).

The streams are asked for well above the control rate (``companion.link.telemetry_rate_hz``,
50 Hz against 10.5), so a healthy vehicle never trips the rule; in lockstep every frame carries
both messages with the frame's own time, so lockstep flights are unchanged by it.
"""

from __future__ import annotations

from dataclasses import dataclass

from companion.msg.snapshot import VehicleSnapshot


@dataclass(frozen=True)
class TelemetryStamps:
    """The vehicle's stamps (ms since its boot) of what an observation is made of."""

    position_ms: int | None
    attitude_ms: int | None

    @classmethod
    def of(cls, snapshot: VehicleSnapshot) -> TelemetryStamps:
        return cls(snapshot.position_time_boot_ms, snapshot.attitude_time_boot_ms)

    @property
    def complete(self) -> bool:
        """Both messages have arrived at least once."""
        return self.position_ms is not None and self.attitude_ms is not None

    def newer_than(self, previous: TelemetryStamps | None) -> bool:
        """Each message newer than in ``previous`` (None: the episode's first step)."""
        if not self.complete:
            return False
        if previous is None:
            return True
        assert self.position_ms is not None and self.attitude_ms is not None
        return (previous.position_ms is None or self.position_ms > previous.position_ms) and (
            previous.attitude_ms is None or self.attitude_ms > previous.attitude_ms)


class FreshnessGate:
    """Remembers the stamps of the last step that flew on them; one per episode loop."""

    def __init__(self) -> None:
        self._last: TelemetryStamps | None = None

    def reset(self) -> None:
        """A new episode: its first step needs only complete telemetry. (Not carried over from
        the previous episode: a rebooted autopilot's clock starts again at zero.)"""
        self._last = None

    def admit(self, snapshot: VehicleSnapshot) -> bool:
        """Whether a step may use ``snapshot``; if so, it becomes the one to beat."""
        stamps = TelemetryStamps.of(snapshot)
        if not stamps.newer_than(self._last):
            return False
        self._last = stamps
        return True
