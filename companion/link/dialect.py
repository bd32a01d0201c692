"""What differs between autopilots, for the session: modes, take-off, hold, land, setpoints.

The session never names a flight mode: it asks the vehicle's :class:`Dialect`, chosen from
the autopilot field of its HEARTBEAT (:func:`dialect_for`). PX4 flies the companion's
setpoints in OFFBOARD, which it enters only while a setpoint stream is fresh; ArduCopter flies
them in GUIDED, which it enters at any time and which is also the mode it takes off in.
Everything here is data and pure functions: the session turns the steps into link calls.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal

from companion.errors import ConfigError

MAV_FRAME_LOCAL_NED = 1
MAV_FRAME_BODY_NED = 8
MAV_FRAME_BODY_FRD = 12
BODY_VELOCITY_TYPE_MASK = 0x5C7  # use vx, vy, vz, yaw rate; ignore position, acceleration, yaw
POSITION_TYPE_MASK = 0x9F8  # use x, y, z, yaw; ignore velocity, acceleration, yaw rate

StepKind = Literal["mode", "arm", "takeoff"]
EndOfRun = Literal["land", "hold"]


@dataclass(frozen=True)
class Step:
    """One action of a sequence: switch to ``mode``, arm, or take off to ``alt_m``."""

    kind: StepKind
    mode: str = ""
    alt_m: float = 0.0


@dataclass(frozen=True)
class Dialect:
    """One autopilot family's way of doing what the session needs."""

    name: str  # "PX4", "ArduPilot"
    offboard_mode: str  # the mode that flies the companion's setpoints
    hold_mode: str  # the vehicle's own hold: stops and keeps position without sticks
    land_mode: str  # the mode a LAND command ends in
    takeoff_mode: str | None  # the mode to be in before arming for a take-off (None: any)
    stream_before_offboard: bool  # the offboard mode is refused unless setpoints are fresh
    land_by_mode: bool  # land by switching to land_mode (else MAV_CMD_NAV_LAND)
    loss_timeout_param: str  # setpoints missing this long -> the vehicle's own reaction
    loss_reaction: str  # what it then does, for logs and docs
    lockstep_marker: str | None  # the frame marker of lockstep (None: no lockstep)
    takeoff_hint: str  # what to check when a take-off is refused
    arm_hint: str
    confirm_takeoff_mode: bool = False
    """Arm only once the HEARTBEAT shows ``takeoff_mode`` (ArduCopter arms in any mode it is in,
    but takes off only from GUIDED: an ACKed mode change can still be undone while it boots)."""
    body_frame: int = MAV_FRAME_BODY_NED  # velocity (forward, right, down) rotated by heading
    body_type_mask: int = BODY_VELOCITY_TYPE_MASK
    position_frame: int = MAV_FRAME_LOCAL_NED
    position_type_mask: int = POSITION_TYPE_MASK
    precland_mode: str = ""
    """The mode that lands on the companion's LANDING_TARGET (companion/link/landing_target.py)."""
    precland_params: tuple[tuple[str, float], ...] = ()
    """Parameters set (PARAM_SET) before entering ``precland_mode``."""
    precland_params_at_boot: bool = False
    """``precland_params`` take effect only at boot: before the run's first arming they are read,
    and if not yet set, set and made effective by a reboot (MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN)."""
    landing_target_frame: int = MAV_FRAME_LOCAL_NED
    """The LANDING_TARGET frame this autopilot reads positions in (it refuses the others)."""

    def is_offboard(self, mode: str) -> bool:
        return mode == self.offboard_mode

    def is_hold(self, mode: str) -> bool:
        return mode == self.hold_mode

    def precland_reboot_needed(self, current: Mapping[str, float | None]) -> bool:
        """Whether the vehicle must reboot for its precision landing: its boot-time parameters
        (``current``, as read; None: unanswered) are not all ``precland_params`` yet."""
        if not self.precland_params_at_boot:
            return False
        return not all(
            (now := current.get(name)) is not None and math.isclose(now, value, abs_tol=1e-3)
            for name, value in self.precland_params
        )

    def takeoff_steps(self, alt_m: float) -> tuple[Step, ...]:
        """From the ground to hovering at ``alt_m`` above home."""
        steps: list[Step] = []
        if self.takeoff_mode is not None:
            steps.append(Step("mode", mode=self.takeoff_mode))
        steps += [Step("arm"), Step("takeoff", alt_m=alt_m)]
        return tuple(steps)

    def end_state_mode(self, policy: EndOfRun) -> str:
        """The mode a run leaves a flying vehicle in."""
        if policy == "land":
            return self.land_mode
        if policy == "hold":
            return self.hold_mode
        raise ConfigError(f"unknown end-of-run policy {policy!r}; use land or hold")


PX4 = Dialect(
    name="PX4",
    offboard_mode="OFFBOARD",
    hold_mode="AUTO.LOITER",
    land_mode="AUTO.LAND",
    takeoff_mode="AUTO.LOITER",  # hold: a vehicle left in AUTO.LAND disarms as soon as it is armed
    stream_before_offboard=True,
    land_by_mode=False,
    loss_timeout_param="COM_OF_LOSS_T",
    loss_reaction="PX4 leaves OFFBOARD for its failsafe (COM_OBL_RC_ACT: hold, then land)",
    lockstep_marker="SYSTEM_TIME",
    takeoff_hint="arm first, and make sure the vehicle has a position estimate",
    arm_hint="read the vehicle's STATUSTEXT pre-arm messages, fix them and retry",
    # Precision landing: its own flight mode; LANDING_TARGET positions only in LOCAL_NED, read as
    # the target's position in the local frame (mavlink_receiver -> landing_target_pose x_abs).
    precland_mode="AUTO.PRECLAND",
    landing_target_frame=MAV_FRAME_LOCAL_NED,
)

ARDUPILOT = Dialect(
    name="ArduPilot",
    offboard_mode="GUIDED",
    hold_mode="BRAKE",
    land_mode="LAND",
    takeoff_mode="GUIDED",
    stream_before_offboard=False,
    land_by_mode=True,
    loss_timeout_param="GUID_TIMEOUT",
    loss_reaction="ArduCopter stays in GUIDED and stops (zero velocity)",
    lockstep_marker=None,
    takeoff_hint="ArduCopter takes off only when armed in GUIDED (set GUIDED before arming)",
    confirm_takeoff_mode=True,
    arm_hint="ArduCopter refuses to arm until its pre-arm checks pass (the EKF settles for "
    "about 40 s after boot); read its 'PreArm:' messages",
    # Precision landing: LAND with AC_PrecLand enabled and its MAVLink (companion) backend; it reads
    # LANDING_TARGET positions only in BODY_FRD (AC_PrecLand_Companion::handle_msg). AC_PrecLand
    # makes its backend at boot: PLND_* set at run time lands vertically ("PrecLand: Failsafe
    # Measures") until a reboot.
    precland_mode="LAND",
    precland_params=(("PLND_ENABLED", 1.0), ("PLND_TYPE", 1.0)),
    precland_params_at_boot=True,
    landing_target_frame=MAV_FRAME_BODY_FRD,
)

_BY_AUTOPILOT = {"PX4": PX4, "ARDUPILOTMEGA": ARDUPILOT}


def dialect_for(autopilot: str) -> Dialect:
    """The dialect of a HEARTBEAT's autopilot name ("PX4", "ARDUPILOTMEGA")."""
    try:
        return _BY_AUTOPILOT[autopilot]
    except KeyError:
        raise ConfigError(
            f"the vehicle's autopilot is {autopilot!r}; the companion flies PX4 and ArduPilot "
            "(HEARTBEAT autopilot MAV_AUTOPILOT_PX4 or MAV_AUTOPILOT_ARDUPILOTMEGA)"
        ) from None
