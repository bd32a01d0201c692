"""The session's port to a vehicle over a MAVLink link: send a setpoint, get the next control
step's telemetry, wait out a lost link.

Two clocks. In lockstep (our SITL) a step is a frame: the port waits for the SITL's frame marker
and echoes it in the setpoint that answers the frame, so the SITL runs the next frame only then.
In real time a step is a tick of the control rate and the telemetry is the newest the link has:
a tick of the wall clock (:class:`Ticker`, ``[companion.session] clock = "wall"``), or of the
vehicle's own clock (:class:`VehicleClockTicker`, ``clock = "vehicle"``: an autopilot's SITL run
faster than real time is flown at the control rate of its own time). Either way each snapshot moves the home frame (companion/link/home.py).
The batched lanes (companion/rl/landing_lane.py) are the same port on our SITL's objects,
without the link.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable

from companion.errors import ColError, LinkError, LinkLost
from companion.link.base import VehicleLink
from companion.link.dialect import Dialect, dialect_for
from companion.link.home import HomeFrame
from companion.msg.setpoint import VelocitySetpoint
from companion.msg.snapshot import VehicleSnapshot

log = logging.getLogger(__name__)
HOLD = VelocitySetpoint(0.0, 0.0, 0.0, 0.0)
LOCKSTEP_FRAME_PATIENCE_S = 300.0
"""In lockstep a frame is waited for as long as the link lives (the link raises LinkLost after
``link_lost_s`` of silence): a frame that came late on a starved machine is the same frame, and
giving up after 2 s (as this once did) turned a busy machine into a recovery, another flight."""
LINK_POLL_S = 0.1


class Ticker:
    """Real-time pacing at a fixed period, with the measured periods kept for reports."""

    def __init__(self, rate_hz: float) -> None:
        self.period_s = 1.0 / rate_hz
        self._next = time.monotonic()
        self.periods_s: list[float] = []
        self._last: float | None = None

    def wait(self) -> None:
        self._next += self.period_s
        delay = self._next - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        else:
            self._next = time.monotonic()  # late: do not try to catch up with a burst
        now = time.monotonic()
        if self._last is not None:
            self.periods_s.append(now - self._last)
        self._last = now


class VehicleClockTicker:
    """Pacing by the vehicle's clock: a step each period of its ``time_boot_ms``, polled every
    ``poll_s`` of wall time. A vehicle whose clock stands still (a frozen or lost vehicle) is
    waited for at most ``patience_s`` of wall time, then the step goes ahead: link loss stays the
    link's wall-clock rule. A late step starts the next period from now (no burst to catch up).
    ``periods_s`` keeps the vehicle time between steps, for reports."""

    def __init__(self, rate_hz: float, vehicle_ms: Callable[[], int | None], *, poll_s: float = 0.002,
                 patience_s: float = 1.0, clock: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], None] = time.sleep) -> None:
        self.period_ms = 1000.0 / rate_hz
        self._vehicle_ms, self._clock, self._sleep = vehicle_ms, clock, sleep
        self.poll_s, self.patience_s = poll_s, patience_s
        self._next_ms: float | None = None
        self._last_ms: int | None = None
        self.periods_s: list[float] = []

    def wait(self) -> None:
        now_ms = self._vehicle_ms()
        if self._next_ms is None:
            self._next_ms = (now_ms if now_ms is not None else 0) + self.period_ms
        deadline = self._clock() + self.patience_s
        while (now_ms is None or now_ms < self._next_ms) and self._clock() < deadline:
            self._sleep(self.poll_s)
            now_ms = self._vehicle_ms()
        if now_ms is None:
            return
        late = now_ms >= self._next_ms + self.period_ms
        self._next_ms = (now_ms if late else self._next_ms) + self.period_ms
        if self._last_ms is not None:
            self.periods_s.append((now_ms - self._last_ms) / 1000.0)
        self._last_ms = now_ms


class LinkPort:
    """One vehicle behind a link, stepped at the control rate (module docstring)."""

    def __init__(self, link: VehicleLink, lockstep: bool, control_rate_hz: float, home: HomeFrame,
                 dialect: Dialect | None = None, clock: str = "wall") -> None:
        self.link, self.lockstep, self.home = link, lockstep, home
        self.control_rate_hz = control_rate_hz
        self.clock = clock
        self.frame_ms = -1
        """Lockstep: the frame being answered (-1: none yet, or the frames start again)."""
        self._ticker: Ticker | VehicleClockTicker | None = None
        self._dialect = dialect

    @property
    def dialect(self) -> Dialect:
        """How this vehicle's autopilot does offboard, hold, land and take-off: as given, else
        from its HEARTBEAT (LinkError while none has come)."""
        if self._dialect is None:
            snap = self.link.state()
            if snap is None:
                raise LinkError("no HEARTBEAT from the vehicle yet: cannot tell its autopilot")
            self._dialect = dialect_for(snap.autopilot)
        return self._dialect

    @property
    def echo(self) -> int | None:
        """The frame a setpoint answers (lockstep), else None."""
        return self.frame_ms if self.lockstep and self.frame_ms >= 0 else None

    def send(self, sp: VelocitySetpoint) -> None:
        self.link.send_velocity_body(sp, echo_time_boot_ms=self.echo)

    def hold_in(self, mode: str) -> None:
        """Hold: the zero setpoint (in lockstep it answers the frame), then ``mode`` (the
        dialect's hold mode); a refused mode is logged, the hold stands."""
        self.send(HOLD)
        try:
            self.link.set_mode(mode)
        except ColError as exc:
            log.error("could not switch to hold: %s", exc)

    def send_position(self, north_m: float, east_m: float, down_m: float, yaw_rad: float) -> None:
        self.link.send_position_ned(north_m, east_m, down_m, yaw_rad, echo_time_boot_ms=self.echo)

    def next_snapshot(self) -> VehicleSnapshot | None:
        """The next control step's telemetry, or None if the link is gone."""
        if self.lockstep:
            try:
                snap = self.link.wait_frame(self.frame_ms, timeout_s=LOCKSTEP_FRAME_PATIENCE_S)
            except LinkLost:  # the link's way of saying "silent": recover like in real time
                return None
            if snap is not None:
                self.frame_ms = int(snap.frame_time_boot_ms or snap.time_boot_ms)
                self.home.update(snap)
            return snap
        if self._ticker is None:
            self._ticker = (VehicleClockTicker(self.control_rate_hz, self._vehicle_ms) if self.clock == "vehicle"
                            else Ticker(self.control_rate_hz))
        self._ticker.wait()
        return self.newest()

    def _vehicle_ms(self) -> int | None:
        snap = self.link.state()
        return None if snap is None else int(snap.time_boot_ms)

    def newest(self) -> VehicleSnapshot | None:
        """The newest telemetry now, without waiting (None: the link is gone)."""
        snap = self.link.state() if self.link.link_alive() else None
        if snap is not None:
            self.home.update(snap)
        return snap

    def wait_for_link(self, patience_s: float, end_requested: Callable[[], str | None]) -> VehicleSnapshot | str:
        """The link is lost: wait for it to come back, its first snapshot; or why the episode
        ends instead: "link_lost" after ``patience_s``, or the reason ``end_requested`` gives
        meanwhile (a person pressing Next or Stop is not kept waiting by a dead link)."""
        deadline = time.monotonic() + patience_s
        while time.monotonic() < deadline:
            time.sleep(LINK_POLL_S)
            asked = end_requested()
            if asked is not None:
                log.warning("the operator ended the episode while the link was lost")
                return asked
            if self.link.link_alive():
                snap = self.link.state()
                if snap is not None:
                    log.warning("link back: resuming")
                    if self.lockstep:
                        self.frame_ms = -1
                        snap = self.next_snapshot()
                    return snap if snap is not None else "link_lost"
        return "link_lost"
