"""The vehicle-side sequences a session runs around its episodes: arming (waiting while the
vehicle is still booting), taking off the way its autopilot wants, and leaving it safe.

Each takes the link and the vehicle's :class:`~companion.link.dialect.Dialect`; none names a
flight mode itself. A vehicle that refuses says why in STATUSTEXT: those reasons are shown
live while waiting, and carried in the error when waiting is over.
"""

from __future__ import annotations

import contextlib
import functools
import logging
import threading
import time
from collections.abc import Callable, Iterator

from companion.errors import ColError, CommandRejected
from companion.link.base import VehicleLink
from companion.link.dialect import Dialect, EndOfRun
from companion.msg.setpoint import VelocitySetpoint

log = logging.getLogger(__name__)
ARM_RETRY_S = 1.0
MODE_CONFIRM_S = 3.0  # HEARTBEAT comes at 1 Hz: three chances to show the new mode
MODE_POLL_S = 0.05


def when_ready(action: Callable[[], None], what: str, timeout_s: float, retry_s: float = ARM_RETRY_S,
               sleep: Callable[[float], None] = time.sleep,
               clock: Callable[[], float] = time.monotonic) -> None:
    """Run ``action`` (arm, or enter the mode armed in), retrying for up to ``timeout_s`` while
    the vehicle refuses (an EKF still settling after boot) and logging each new reason it gives.
    A refusal by the companion is not retried."""
    start = clock()
    shown: list[str] = []
    while True:
        try:
            action()
            if shown:
                log.warning("%s accepted after %.0f s of waiting", what, clock() - start)
            return
        except CommandRejected as exc:
            if exc.origin != "vehicle":
                raise
            waited = clock() - start
            for reason in exc.reasons or (f"{exc.command} refused: {exc.result}",):
                if reason not in shown:
                    shown.append(reason)
                    log.warning("waiting for the vehicle to %s (%.0f s of %.0f): %s", what, waited, timeout_s, reason)
            if waited + retry_s > timeout_s:
                raise CommandRejected(
                    exc.command, exc.result,
                    f"still refused after {waited:.0f} s of retrying (companion.session.arm_timeout_s); "
                    "fix what the vehicle says, or wait longer",
                    reasons=tuple(shown),
                ) from exc
            sleep(retry_s)


def arm_when_ready(link: VehicleLink, timeout_s: float) -> None:
    """Arm, waiting up to ``timeout_s`` while the vehicle is not armable yet."""
    when_ready(link.arm, "arm", timeout_s)


def enter_confirmed(link: VehicleLink, mode: str, confirm_s: float = MODE_CONFIRM_S,
                    sleep: Callable[[float], None] = time.sleep,
                    clock: Callable[[], float] = time.monotonic) -> None:
    """Switch to ``mode`` and wait until the vehicle's HEARTBEAT says so; a vehicle that ACKs the
    change but keeps flying another mode counts as refusing (``when_ready`` then retries)."""
    link.set_mode(mode)
    deadline = clock() + confirm_s
    while True:
        snap = link.state()
        if snap is not None and snap.mode == mode:
            return
        if clock() >= deadline:
            shown = snap.mode if snap is not None else "nothing"
            raise CommandRejected(f"set_mode({mode!r})", "NOT_CONFIRMED",
                                  f"accepted, but the HEARTBEAT still says {shown} after {confirm_s:g} s",
                                  reasons=(f"mode is {shown}, not {mode}",))
        sleep(MODE_POLL_S)


def arm_in_mode(link: VehicleLink, mode: str, confirm: Callable[[], None]) -> None:
    """Arm, making sure first that the vehicle is in ``mode`` (``confirm`` enters it otherwise)."""
    snap = link.state()
    if snap is None or snap.mode != mode:
        confirm()
    link.arm()


def take_off(link: VehicleLink, dialect: Dialect, alt_m: float, arm_timeout_s: float,
             sleep: Callable[[float], None] = time.sleep,
             clock: Callable[[], float] = time.monotonic) -> None:
    """From the ground to climbing towards ``alt_m``: the dialect's steps (ArduPilot: GUIDED,
    confirmed by HEARTBEAT, arm, NAV_TAKEOFF; PX4: AUTO.LOITER, arm, NAV_TAKEOFF). The caller
    waits for the altitude. A take-off the vehicle refuses is asked once more after the mode is
    entered again (if the vehicle left it) and the vehicle armed again: ArduCopter refuses it
    armed in another mode, and when its disarm after the last landing falls between our arm (an
    armed vehicle ACKs it without restarting that timer) and the take-off, its HEARTBEAT still
    saying armed in GUIDED (once in CI on a loaded machine at 5x)."""
    mode = dialect.takeoff_mode
    if mode is None or not dialect.confirm_takeoff_mode:
        for step in dialect.takeoff_steps(alt_m):
            if step.kind == "mode":
                when_ready(functools.partial(link.set_mode, step.mode), f"enter {step.mode}", arm_timeout_s)
            elif step.kind == "arm":
                arm_when_ready(link, arm_timeout_s)
            else:
                link.takeoff(step.alt_m)
        _ask_home(link)
        return
    confirm = functools.partial(enter_confirmed, link, mode, sleep=sleep, clock=clock)
    arm = functools.partial(arm_in_mode, link, mode, confirm)
    when_ready(confirm, f"enter {mode}", arm_timeout_s, sleep=sleep, clock=clock)
    when_ready(arm, f"arm in {mode}", arm_timeout_s, sleep=sleep, clock=clock)
    try:
        link.takeoff(alt_m)
    except CommandRejected as exc:
        if exc.origin != "vehicle":
            raise
        snap = link.state()
        shown = "nothing" if snap is None else f"{snap.mode}, {'armed' if snap.armed else 'disarmed'}"
        log.warning("take-off refused (%s; the vehicle shows %s): %s again, armed, and asking once more",
                    exc, shown, mode)
        when_ready(arm, f"arm in {mode}", arm_timeout_s, sleep=sleep, clock=clock)
        link.takeoff(alt_m)
    _ask_home(link)


def _ask_home(link: VehicleLink) -> None:
    """Arming sets home: ask for the new HOME_POSITION now rather than at its next 2 s beat."""
    try:
        link.request_message("HOME_POSITION", timeout_s=1.0)
    except ColError as exc:  # heights then use the last home heard; nothing to stop for
        log.info("HOME_POSITION not sent on request: %s", exc)


def leave_safe(link: VehicleLink, dialect: Dialect, policy: EndOfRun) -> str:
    """Put the vehicle in a state that needs nobody: land (or hold) if flying, disarm if it
    sits armed on the ground. Never raises (it runs while unwinding); returns what it did."""
    if not link.link_alive():
        log.error("cannot leave the vehicle safe: the link is lost; its own failsafe acts")
        return "link lost"
    snap = link.state()
    if snap is None or not snap.armed:
        return "disarmed"
    if snap.landed_state == "ON_GROUND":
        try:
            link.disarm()
            return "disarmed"
        except CommandRejected as exc:  # it says it is not on the ground after all: land or hold
            log.warning("disarm refused (%s); %s instead", exc, policy)
    mode = dialect.end_state_mode(policy)
    try:
        if policy == "land" and not dialect.land_by_mode:
            link.land()
        else:
            link.set_mode(mode)
    except ColError as exc:
        log.error("could not leave the vehicle safe (%s): %s; take over", policy, exc)
        return f"failed: {exc}"
    log.info("vehicle left in %s (%s)", mode, policy)
    return mode


@contextlib.contextmanager
def streaming(link: VehicleLink, setpoint: VelocitySetpoint, period_s: float) -> Iterator[None]:
    """Keep sending ``setpoint`` every ``period_s`` from a thread while the block runs.

    Why: PX4 holds OFFBOARD only while setpoints keep coming (``COM_OF_LOSS_T``, 1 s), and a
    mode request blocks until its COMMAND_ACK. On a lossy link the ACK is lost one time in ten;
    the request is sent again a second later, and with the stream paused meanwhile the vehicle
    has given OFFBOARD up (or refuses it: "stream setpoints first"). Real time only: in lockstep
    every setpoint answers a frame and nothing is lost.
    """
    stop = threading.Event()

    def run() -> None:
        while not stop.wait(period_s):
            try:
                link.send_velocity_body(setpoint)
            except ColError:  # a lost link: the caller's own wait reports it
                pass

    thread = threading.Thread(target=run, name="hold-stream", daemon=True)
    thread.start()
    try:
        yield
    finally:
        stop.set()
        thread.join()
