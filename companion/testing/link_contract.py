"""A contract any :class:`~companion.link.VehicleLink` backend must meet, as checks to run.

Like Gymnasium's ``check_env``: hand it a *connected* link to a vehicle on the ground (the
fake vehicle, the SITL, or MAVSDK's view of either) and each check either returns quietly or
raises :class:`LinkContractViolation` saying what is wrong. The checks only use what every
conforming vehicle does, so they need no knobs of the fake.

    link = open_link(cfg); link.connect()
    run_link_contract(link)
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable

from companion.errors import CommandRejected
from companion.link.base import VehicleLink
from companion.msg.setpoint import VelocitySetpoint
from companion.msg.snapshot import LANDED_STATES, VehicleSnapshot


class LinkContractViolation(AssertionError):
    """A backend broke the VehicleLink contract."""


def _require(condition: bool, message: str) -> None:
    if not condition:
        raise LinkContractViolation(message)


def _eventually(
    link: VehicleLink, test: Callable[[VehicleSnapshot], bool], timeout_s: float
) -> VehicleSnapshot | None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        snapshot = link.state()
        if snapshot is not None and test(snapshot):
            return snapshot
        time.sleep(0.02)
    return None


def check_snapshot(link: VehicleLink) -> VehicleSnapshot:
    """A connected link has a complete, finite, immutable snapshot and says it is alive."""
    snapshot = link.state()
    _require(snapshot is not None, "state() is None after connect()")
    assert snapshot is not None
    _require(link.link_alive(), "link_alive() is False right after connect()")
    for name in ("position_ned_m", "velocity_ned_m_s", "attitude_rad", "rates_frd_rad_s"):
        value = getattr(snapshot, name)
        _require(
            len(value) == 3 and all(math.isfinite(v) for v in value),
            f"snapshot.{name} = {value!r} is not three finite numbers",
        )
    _require(snapshot.landed_state in LANDED_STATES, f"landed_state {snapshot.landed_state!r}")
    _require(isinstance(snapshot.mode, str) and snapshot.mode != "", "mode is empty")
    try:
        snapshot.armed = not snapshot.armed  # type: ignore[misc]
    except AttributeError:
        return snapshot
    raise LinkContractViolation("VehicleSnapshot can be modified; it must be frozen")


def check_telemetry_flows(link: VehicleLink, timeout_s: float = 2.0) -> None:
    """Position and attitude arrive, and the snapshot is replaced (not mutated) as they do."""
    first = link.state()
    later = _eventually(
        link, lambda s: s is not first and s.position_valid and s.attitude_valid, timeout_s
    )
    _require(later is not None, f"no position and attitude telemetry within {timeout_s} s")
    assert first is not None and later is not None
    _require(later.received_s >= first.received_s, "received_s went backwards")


def check_frames(link: VehicleLink, count: int = 3, timeout_s: float = 2.0) -> None:
    """wait_frame returns successive frames with increasing time_boot_ms, None when none comes."""
    snapshot = link.state()
    assert snapshot is not None
    last = snapshot.frame_time_boot_ms if snapshot.frame_time_boot_ms is not None else -1
    for _ in range(count):
        frame = link.wait_frame(last, timeout_s)
        _require(frame is not None, f"wait_frame({last}) returned no frame within {timeout_s} s")
        assert frame is not None
        stamp = frame.frame_time_boot_ms
        _require(stamp is not None and stamp > last, f"frame {stamp} is not newer than {last}")
        assert stamp is not None
        last = stamp
    _require(link.wait_frame(2**32, 0.05) is None, "wait_frame for a future frame did not time out")


def check_mode_change(link: VehicleLink, mode: str = "AUTO.LOITER", timeout_s: float = 3.0) -> None:
    """set_mode is ACKed and the vehicle's heartbeat then shows the mode."""
    link.set_mode(mode)
    shown = _eventually(link, lambda s: s.mode == mode, timeout_s)
    _require(shown is not None, f"mode {mode} not shown within {timeout_s} s (got {link.state()})")


def check_unknown_mode_rejected(link: VehicleLink) -> None:
    """An unknown mode name is refused with CommandRejected before anything is sent."""
    try:
        link.set_mode("NO_SUCH_MODE")
    except CommandRejected as exc:
        _require(exc.result == "UNSUPPORTED", f"unknown mode gave result {exc.result!r}")
        return
    raise LinkContractViolation("set_mode('NO_SUCH_MODE') did not raise CommandRejected")


def check_arm_disarm(link: VehicleLink, timeout_s: float = 3.0) -> None:
    """arm() then disarm() on the ground, each visible in the snapshot."""
    link.arm()
    _require(_eventually(link, lambda s: s.armed, timeout_s) is not None, "armed never shown")
    link.disarm()
    _require(_eventually(link, lambda s: not s.armed, timeout_s) is not None, "disarm never shown")


def check_setpoint_guards(link: VehicleLink) -> None:
    """Out-of-range setpoints and stamps raise ValueError instead of being sent."""
    bad_calls: list[tuple[str, Callable[[], None]]] = [
        ("1000 m/s forward", lambda: link.send_velocity_body(VelocitySetpoint(1000.0, 0, 0, 0))),
        ("100 rad/s yaw rate", lambda: link.send_velocity_body(VelocitySetpoint(0, 0, 0, 100.0))),
        ("negative echo", lambda: link.send_velocity_body(VelocitySetpoint.zero(), -5)),
        ("NaN position", lambda: link.send_position_ned(float("nan"), 0.0, -2.0, 0.0)),
        ("position 1e7 m away", lambda: link.send_position_ned(1e7, 0.0, -2.0, 0.0)),
    ]
    for label, call in bad_calls:
        try:
            call()
        except ValueError:
            continue
        raise LinkContractViolation(f"a setpoint with {label} was accepted")


def check_velocity_stream(link: VehicleLink, count: int = 5, period_s: float = 0.05) -> None:
    """A short stream of valid body-velocity setpoints goes out without error."""
    before = link.stats().setpoints_sent
    for _ in range(count):
        link.send_velocity_body(VelocitySetpoint(0.0, 0.0, 0.0, 0.0))
        time.sleep(period_s)
    sent = link.stats().setpoints_sent - before
    _require(sent == count, f"stats().setpoints_sent grew by {sent}, expected {count}")


def run_link_contract(link: VehicleLink, *, arm: bool = True, frames: bool = True) -> list[str]:
    """Run every check on a connected link to a vehicle on the ground; names of checks run.

    ``arm=False`` skips arming (a real vehicle); ``frames=False`` skips frame checks for a
    vehicle that sends no frame markers.
    """
    checks: list[tuple[str, Callable[[], object]]] = [
        ("snapshot", lambda: check_snapshot(link)),
        ("telemetry_flows", lambda: check_telemetry_flows(link)),
        ("mode_change", lambda: check_mode_change(link)),
        ("unknown_mode_rejected", lambda: check_unknown_mode_rejected(link)),
        ("setpoint_guards", lambda: check_setpoint_guards(link)),
        ("velocity_stream", lambda: check_velocity_stream(link)),
    ]
    if frames:
        checks.append(("frames", lambda: check_frames(link)))
    if arm:
        checks.append(("arm_disarm", lambda: check_arm_disarm(link)))
    for _, check in checks:
        check()
    return [name for name, _ in checks]
