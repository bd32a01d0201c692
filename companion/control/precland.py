"""The baseline an operator would fly: the autopilot's own precision landing, fed by the companion.

Before the run's first arming, an autopilot whose precision landing is made at boot (ArduCopter's
PLND_*) gets its parameters and a reboot if they are not set yet (:meth:`PrecisionLander.prepare`).
After the episode's start (the companion flew there), the landing is handed over: the dialect's
parameters and mode (PX4 AUTO.PRECLAND; ArduPilot PLND_* and LAND), then one LANDING_TARGET per
camera frame in which the pad's board is decoded (companion/link/landing_target.py has the
contract), until the vehicle reports touchdown (:func:`fly_precland`, the episode after its start,
through the session's :class:`~companion.control.link_port.LinkPort`). Nothing here flies the
vehicle.
"""

from __future__ import annotations

import contextlib
import itertools
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass

from colcommon.frames import Frame
from companion.control.link_port import HOLD, LinkPort
from companion.errors import CommandRejected, LinkTimeout
from companion.link.base import VehicleLink
from companion.link.dialect import Dialect
from companion.link.landing_target import LandingTarget, landing_target
from companion.link.sim_params import PARAM_BUDGET_S
from companion.msg.snapshot import VehicleSnapshot
from companion.vision.aruco import ArucoPadDetector
from companion.vision.camera import CameraSource, SitlCameraSource, lockstep_frame

log = logging.getLogger(__name__)


def _listed(values: dict[str, float | None]) -> str:
    return ", ".join(f"{name}={'unread' if v is None else f'{v:g}'}" for name, v in values.items())
PARAM_TOLERANCE = 1e-3
REBOOT_SILENT_WITHIN_S = 10.0  # an ACKed reboot goes silent within this (ArduCopter: at once)
REBOOT_BACK_WITHIN_S = 60.0  # and its HEARTBEAT comes back within this (a flight controller: ~5-30 s)
HEARTBEAT_GONE_S = 3.0  # no autopilot HEARTBEAT this long: it is rebooting (they come at 1 Hz)
POLL_S = 0.05


def await_reboot(link: VehicleLink, silent_within_s: float = REBOOT_SILENT_WITHIN_S,
                 back_within_s: float = REBOOT_BACK_WITHIN_S, clock: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], None] = time.sleep) -> None:
    """The autopilot's HEARTBEAT goes away and comes back: only then did the boot-time parameters
    take effect. (Its HEARTBEAT, not the link: other components of its system, a camera, keep
    talking.) ``clock`` is the link's. LinkTimeout saying which half did not happen."""
    def last_heartbeat_s() -> float:
        snap = link.state()
        return -math.inf if snap is None else snap.heartbeat_s

    if not _wait_until(lambda: clock() - last_heartbeat_s() > HEARTBEAT_GONE_S, silent_within_s, clock, sleep):
        raise LinkTimeout(f"the vehicle ACKed the reboot but its HEARTBEAT kept coming for {silent_within_s:g} s: "
                          "it did not reboot, so its boot-time precision landing parameters are not in effect; "
                          "reboot it from the ground station and retry")
    gone_s = last_heartbeat_s()
    log.info("precision landing: the vehicle went silent for its reboot; waiting up to %.0f s", back_within_s)
    if not _wait_until(lambda: last_heartbeat_s() > gone_s and link.link_alive(), back_within_s, clock, sleep):
        raise LinkTimeout(f"the vehicle went silent for its reboot and its HEARTBEAT did not come back within "
                          f"{back_within_s:g} s; check that it booted (power, its console) and fly again")


def _wait_until(done: Callable[[], bool], timeout_s: float, clock: Callable[[], float],
                sleep: Callable[[float], None]) -> bool:
    deadline = clock() + timeout_s
    while not done():
        if clock() >= deadline:
            return False
        sleep(POLL_S)
    return True


@dataclass
class PreclandCounts:
    """One episode's frames, detections and messages sent, for its record."""

    frames: int = 0
    detections: int = 0
    sent: int = 0
    refused: int = 0  # detections that made no valid LANDING_TARGET (non-finite telemetry)

    def note(self) -> str:
        return (f"precland: {self.sent} LANDING_TARGET from {self.frames} camera frames "
                f"({self.detections} with the board decoded)")


class PrecisionLander:
    """Asks for the autopilot's precision landing and streams LANDING_TARGET from the camera."""

    def __init__(self, link: VehicleLink, camera: CameraSource | None, detector: ArucoPadDetector,
                 frame_timeout_s: float = 0.5, clock: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], None] = time.sleep) -> None:
        self.link = link
        self.clock, self.sleep = clock, sleep  # the reboot's waits (tests pass their own)
        self.camera = camera
        self.detector = detector
        self.frame_timeout_s = frame_timeout_s
        self.counts = PreclandCounts()
        self.sent: list[LandingTarget] = []  # this episode's, in order (tests and records read it)
        self._last_frame_ms = -1
        # Frames of our SITL and of the rendered camera carry the vehicle's boot time; any other
        # camera's stamps are its own, so the telemetry's time stands in for them.
        self._vehicle_clock = isinstance(camera, SitlCameraSource) or bool(getattr(camera, "vehicle_time_stamps", False))

    def begin(self) -> None:
        self.counts = PreclandCounts()
        self.sent = []
        if self.camera is None:
            log.warning("precland without a camera: no LANDING_TARGET will be sent; the autopilot lands without a target")

    def prepare(self, dialect: Dialect) -> bool:
        """Before the run's first arming: parameters the autopilot reads only at boot, set and
        made effective by a reboot while disarmed (nothing when already set). True: rebooted."""
        if not dialect.precland_params_at_boot:
            return False
        current = {name: self.link.read_param(name, PARAM_BUDGET_S) for name, _ in dialect.precland_params}
        if not dialect.precland_reboot_needed(current):
            log.info("precision landing: %s already in effect", _listed(current))
            return False
        snap = self.link.state()
        if snap is None or snap.armed:
            raise CommandRejected("reboot for precision landing", "ARMED", f"{_listed(current)}: {dialect.name} "
                                  "applies them at boot only; land and disarm it, then fly again", origin="companion")
        self._set_params(dialect)
        log.warning("precision landing: %s reads %s at boot only: rebooting it (disarmed)", dialect.name,
                    ", ".join(name for name, _ in dialect.precland_params))
        self._reboot()
        self.link.request_rates()  # streams start afresh after a boot, as after connecting
        return True

    def _reboot(self) -> None:
        try:
            self.link.reboot()
        except LinkTimeout as exc:  # the ACK may be lost to the reboot itself: the silence decides
            log.warning("precision landing: %s; waiting for the vehicle to go silent anyway", exc)
        await_reboot(self.link, clock=self.clock, sleep=self.sleep)

    def engage(self, dialect: Dialect) -> None:
        """The dialect's parameters (each checked against the vehicle's echo), then its mode."""
        if not dialect.precland_mode:
            raise CommandRejected("precision landing", "UNSUPPORTED", f"{dialect.name} has no precision landing mode here",
                                  origin="companion")
        self._set_params(dialect)
        self.link.set_mode(dialect.precland_mode)
        log.info("precision landing: %s asked (%s)", dialect.precland_mode,
                 ", ".join(f"{n}={v:g}" for n, v in dialect.precland_params) or "no parameters")

    def _set_params(self, dialect: Dialect) -> None:
        """Each of the dialect's parameters, confirmed by the vehicle's PARAM_VALUE echo (waited for
        as an episode's simulator parameters are: a loaded autopilot at 4-5x answers late)."""
        for name, value in dialect.precland_params:
            echoed = self.link.set_param(name, value, PARAM_BUDGET_S)
            if echoed is None or not math.isclose(echoed, value, abs_tol=PARAM_TOLERANCE):
                raise CommandRejected(f"PARAM_SET {name}={value:g}", "NOT_CONFIRMED",
                                      f"the vehicle echoed {echoed}; set it at the ground station and retry")

    def frame(self, snap: VehicleSnapshot, lockstep: bool) -> Frame | None:
        """Lockstep: the frame of this step. Real time: the next frame after the last one used
        (waiting for it paces the loop at the camera's rate)."""
        if self.camera is None:
            return None
        if lockstep and snap.frame_time_boot_ms is not None:
            return lockstep_frame(self.camera, int(snap.frame_time_boot_ms), self.frame_timeout_s)
        frame = self.camera.frame_at(self._last_frame_ms + 1, self.frame_timeout_s)
        if frame is not None:
            self._last_frame_ms = frame.time_boot_ms
        return frame

    def target(self, frame: Frame, snap: VehicleSnapshot, dialect: Dialect) -> LandingTarget | None:
        """The LANDING_TARGET for one frame (None: the board is not decoded in it)."""
        try:
            pose = self.detector.detect(frame.image)
        except ValueError as exc:  # a corrupt image or another camera's size: no target from it
            log.warning("precland: frame %d unusable: %s", frame.frame_number, exc)
            return None
        if pose is None:
            return None
        self.counts.detections += 1
        stamp = frame.time_boot_ms if self._vehicle_clock else snap.time_boot_ms
        try:
            return landing_target(pose, self.detector.camera_matrix, stamp, dialect.landing_target_frame,
                                  snap.attitude_rad, snap.position_ned_m)
        except ValueError as exc:  # non-finite telemetry: never a target the vehicle would fly to
            self.counts.refused += 1
            log.warning("precland: no LANDING_TARGET for frame %d: %s", frame.frame_number, exc)
            return None

    def feed(self, snap: VehicleSnapshot, lockstep: bool, dialect: Dialect) -> LandingTarget | None:
        """One camera frame: detect, and send its LANDING_TARGET when the pad is seen."""
        frame = self.frame(snap, lockstep)
        if frame is None:
            return None
        if not lockstep:  # waiting for the frame took time: place it from the pose it was drawn with, not the older one
            snap = fresher(snap, self.link.state())
        self.counts.frames += 1
        target = self.target(frame, snap, dialect)
        if target is not None:
            self.link.send_landing_target(target)
            self.counts.sent += 1
            self.sent.append(target)
        return target


def fresher(snap: VehicleSnapshot, latest: VehicleSnapshot | None) -> VehicleSnapshot:
    """The newer of two snapshots (a real-time frame comes after the step's snapshot: its target is
    placed from the vehicle's pose when it arrived, which the frame was drawn from or near)."""
    return latest if latest is not None and latest.time_boot_ms >= snap.time_boot_ms else snap


def precland_time_is_up(step: int, elapsed_ms: int, max_steps: int, control_rate_hz: float, lockstep: bool) -> bool:
    """Whether a precision-landing episode has had its time: ``max_steps`` control periods.
    In lockstep a step is a control period (the count decides, as for every other episode); in
    real time a step is a camera frame (LANDING_TARGET goes out at the camera's rate, 30 Hz for a
    rendered camera), so the vehicle's clock decides, and the step count only bounds a clock that
    stands still (at 20 frames per control period)."""
    if lockstep:
        return step >= max_steps
    return elapsed_ms >= 1000.0 * max_steps / control_rate_hz or step >= 20 * max_steps


def fly_precland(lander: PrecisionLander, port: LinkPort, dialect: Dialect, snap: VehicleSnapshot | None, *,
                 max_steps: int, recover: Callable[[], VehicleSnapshot | str],
                 stop: Callable[[int, VehicleSnapshot], str | None],
                 asking: contextlib.AbstractContextManager[None] | None = None) -> tuple[str, int, VehicleSnapshot | None]:
    """An episode the autopilot lands, from its first snapshot ``snap``: (outcome, steps, last
    snapshot). The landing is asked for within ``asking`` (PX4 leaves OFFBOARD only once the ACK is
    in: the session keeps its hold stream flowing meanwhile), then each step is one LANDING_TARGET
    per camera frame, until :func:`precland_time_is_up` ("timeout") or ``stop`` (the episode's one
    rule, companion/control/outcome.py) gives the reason it ends. A lost link (None) waits for
    ``recover``: its first snapshot, or why the episode ends. In lockstep each frame is still
    answered (a zero setpoint the vehicle does not fly)."""
    lander.begin()
    with asking if asking is not None else contextlib.nullcontext():
        lander.engage(dialect)
    outcome, steps = "timeout", 0
    started_ms = snap.time_boot_ms if snap is not None else None
    for step in itertools.count():
        if snap is None:
            recovered = recover()
            if isinstance(recovered, str):
                return recovered, steps, None
            snap = recovered
        if started_ms is None:
            started_ms = snap.time_boot_ms
        if precland_time_is_up(step, snap.time_boot_ms - started_ms, max_steps, port.control_rate_hz, port.lockstep):
            break
        reason = stop(step, snap)
        if reason is not None:
            outcome = reason
            break
        steps = step + 1
        lander.feed(snap, port.lockstep, dialect)
        snap = _next_snapshot(lander, port)
    return outcome, steps, snap


def _next_snapshot(lander: PrecisionLander, port: LinkPort) -> VehicleSnapshot | None:
    """Lockstep: answer this frame, then the next. Real time: the newest telemetry (the wait
    for the camera's next frame paced the step; without a camera the control rate does)."""
    if port.lockstep:
        port.send(HOLD)
        return port.next_snapshot()
    if lander.camera is None:
        return port.next_snapshot()
    return port.newest()
