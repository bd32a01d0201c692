"""The vehicle as the companion sees it: one interface, whatever library talks MAVLink.

Backends (pymavlink, MAVSDK) run their own I/O thread; callers get immutable snapshots and
blocking calls that raise :mod:`companion.errors` types (``LinkLost``, ``LinkTimeout``,
``CommandRejected``) with a hint of what to do.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from companion.errors import LinkError
from companion.link.manual_control import ManualControlMessage
from companion.msg.setpoint import VelocitySetpoint
from companion.msg.snapshot import VehicleSnapshot

if TYPE_CHECKING:
    from companion.link.landing_target import LandingTarget

ManualControlCallback = Callable[[ManualControlMessage], None]


@dataclass(frozen=True)
class LinkStats:
    """Counters a session logs and tests assert on."""

    messages_received: int = 0
    bad_data: int = 0
    telemetry_rejected: int = 0  # telemetry carrying non-finite values, ignored
    manual_control_received: int = 0
    manual_control_dropped: int = 0  # out-of-range axes
    callback_errors: int = 0
    setpoints_sent: int = 0
    link_losses: int = 0
    reconnections: int = 0
    thread_errors: int = 0


@dataclass(frozen=True)
class SetpointLimits:
    """The last line of defence: the link refuses anything beyond these."""

    max_speed_m_s: float = 10.0
    max_yaw_rate_rad_s: float = 3.0
    max_distance_m: float = 1000.0

    def check_velocity(self, sp: VelocitySetpoint) -> None:
        speed = max(abs(sp.forward_m_s), abs(sp.right_m_s), abs(sp.down_m_s))
        if speed > self.max_speed_m_s:
            raise ValueError(
                f"velocity setpoint {sp} exceeds the link's limit of {self.max_speed_m_s} m/s; "
                "clip it in the commands module or raise companion.link.setpoint_max_speed_m_s"
            )
        if abs(sp.yaw_rate_rad_s) > self.max_yaw_rate_rad_s:
            raise ValueError(
                f"yaw rate {sp.yaw_rate_rad_s} rad/s exceeds the link's limit of "
                f"{self.max_yaw_rate_rad_s}; clip it or raise companion.link.setpoint_max_yaw_rate_rad_s"
            )

    def check_position(self, north_m: float, east_m: float, down_m: float, yaw_rad: float) -> None:
        values = {"north_m": north_m, "east_m": east_m, "down_m": down_m, "yaw_rad": yaw_rad}
        for name, value in values.items():
            if not math.isfinite(value):
                raise ValueError(f"position setpoint {name}={value} is not finite; drop it")
        if max(abs(north_m), abs(east_m), abs(down_m)) > self.max_distance_m:
            raise ValueError(
                f"position setpoint ({north_m}, {east_m}, {down_m}) is further than "
                f"{self.max_distance_m} m from the origin; check the frame or raise "
                "companion.link.setpoint_max_distance_m"
            )
        if abs(yaw_rad) > 2 * math.pi:
            raise ValueError(f"yaw {yaw_rad} rad is outside [-2pi, 2pi]; wrap it first")


class VehicleLink(ABC):
    """ "The vehicle": telemetry in, commands and setpoints out.

    Calls other than :meth:`state`, :meth:`link_alive`, :meth:`stats` and :meth:`close` raise
    ``LinkLost`` when nothing has been heard from the vehicle for ``link_lost_s``; the link
    keeps listening and resumes by itself when the vehicle is heard again.
    """

    @abstractmethod
    def connect(self, timeout_s: float | None = None) -> VehicleSnapshot:
        """Start I/O and wait for the vehicle's heartbeat; LinkTimeout if none comes.

        ``timeout_s`` defaults to ``heartbeat_timeout_s`` of the link's config.
        """

    @abstractmethod
    def close(self) -> None:
        """Stop threads, release the port, close the tlog. Idempotent."""

    @abstractmethod
    def state(self) -> VehicleSnapshot | None:
        """The newest snapshot (None before the first heartbeat)."""

    @abstractmethod
    def wait_frame(self, after_time_boot_ms: int, timeout_s: float) -> VehicleSnapshot | None:
        """The first snapshot whose frame marker is newer than ``after_time_boot_ms``.

        In lockstep the frame marker is the SITL's SYSTEM_TIME; in real time it is the next
        telemetry update. None on timeout.
        """

    @abstractmethod
    def arm(self) -> None: ...

    @abstractmethod
    def disarm(self) -> None: ...

    @abstractmethod
    def set_mode(self, name: str) -> None:
        """Switch flight mode by the autopilot's name (PX4: "OFFBOARD", "AUTO.LOITER", "HOLD";
        ArduPilot: "GUIDED", "BRAKE", "LAND"); which to use is the dialect's (link/dialect.py).
        A name the autopilot lacks: ``CommandRejected`` with origin "companion", nothing sent."""

    @abstractmethod
    def takeoff(self, alt_m: float) -> None:
        """Take off to ``alt_m`` above home."""

    @abstractmethod
    def land(self) -> None: ...

    @abstractmethod
    def send_velocity_body(
        self, sp: VelocitySetpoint, echo_time_boot_ms: int | None = None
    ) -> None:
        """Stream one body-frame velocity setpoint; ``echo_time_boot_ms`` answers a lockstep frame."""

    @abstractmethod
    def send_position_ned(
        self,
        north_m: float,
        east_m: float,
        down_m: float,
        yaw_rad: float,
        echo_time_boot_ms: int | None = None,
    ) -> None:
        """Stream one local-NED position setpoint."""

    @abstractmethod
    def request_rates(self, rates_hz: Mapping[str, float] | None = None) -> dict[str, str]:
        """Ask for telemetry rates (message name -> Hz); returns message name -> result name."""

    @abstractmethod
    def request_message(
        self, message_name: str, component_id: int = 1, timeout_s: float = 2.0
    ) -> dict[str, Any] | None:
        """Ask one component of the vehicle's system for one message (MAV_CMD_REQUEST_MESSAGE).

        Returns the message's fields by MAVLink name (strings decoded), or None when the
        component does not answer within ``timeout_s`` (it may not exist: a camera that is not
        there). Raises ``CommandRejected`` when it refuses, ValueError for an unknown name.
        """

    @abstractmethod
    def link_alive(self) -> bool: ...

    @abstractmethod
    def on_manual_control(self, callback: ManualControlCallback | None) -> None:
        """Register (or with None remove) the receiver of checked MANUAL_CONTROL inputs.

        It runs on the link's I/O thread: keep it short (hand the value over, return).
        """

    @abstractmethod
    def stats(self) -> LinkStats: ...

    def read_param(self, name: str, timeout_s: float | None = None) -> float | None:
        """One of the vehicle's parameters by name (PARAM_REQUEST_READ); None when the vehicle
        does not answer within ``timeout_s`` (None: as long as a command is tried, ``command_timeout_s``
        x (1 + ``command_retries``)) or this backend cannot ask."""
        return None

    def set_param(self, name: str, value: float, timeout_s: float | None = None) -> float | None:
        """Set one of the vehicle's parameters (PARAM_SET); the value it echoes in PARAM_VALUE,
        or None when no echo came within ``timeout_s`` (None: as :meth:`read_param`). A backend
        that cannot: LinkError."""
        raise LinkError(f"this link ({type(self).__name__}) cannot set parameters; use the pymavlink link")

    def force_disarm(self) -> None:
        """MAV_CMD_COMPONENT_ARM_DISARM forced (param2 21196): disarmed whatever the vehicle's own
        checks say. Only for a SITL's vehicle standing on the ground its land detector has not
        recognised (companion/control/truth_contact.py). A backend that cannot: LinkError."""
        raise LinkError(f"this link ({type(self).__name__}) cannot force a disarm; use the pymavlink link")

    def reboot(self) -> None:
        """MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN (param1 = 1: reboot the autopilot), ACKed; the
        vehicle then goes silent and comes back by itself. A backend that cannot: LinkError."""
        raise LinkError(f"this link ({type(self).__name__}) cannot reboot the vehicle; use the pymavlink link")

    def send_landing_target(self, target: LandingTarget) -> None:
        """Send one LANDING_TARGET (companion/link/landing_target.py) for the vehicle's precision
        landing. A backend that cannot: LinkError."""
        raise LinkError(f"this link ({type(self).__name__}) cannot send LANDING_TARGET; use the pymavlink link")

    def send_statustext(self, text: str, severity: int = 4) -> bool:
        """Tell the ground stations (STATUSTEXT, at most 50 characters; ``severity`` is
        MAV_SEVERITY, 4 = WARNING). False: this link cannot send it (nothing was sent)."""
        return False

    def __enter__(self) -> VehicleLink:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
