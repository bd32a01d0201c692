"""MAVSDK's names, results and telemetry types, turned into the companion's.

Pure functions and tables, kept apart from :mod:`companion.link.mavsdk_link` (which runs the
event loop) so that they read and test without a vehicle.
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import replace
from types import SimpleNamespace
from typing import Any

from companion.errors import CommandRejected, LinkLost, LinkTimeout
from companion.link.connection import parse_connection
from companion.link.telemetry import HANDLERS, apply_message, with_changes
from companion.msg.snapshot import VehicleSnapshot

DIRECT_TELEMETRY = ("LOCAL_POSITION_NED", "ATTITUDE")
"""What the MAVSDK link reads as raw MAVLink (MavlinkDirect) instead of through MAVSDK's
telemetry plugin, whose position has no stamp and whose attitude stamp is not the message's."""
DIRECT_TRUTH = ("HIL_STATE_QUATERNION", "SIM_STATE", "GPS_GLOBAL_ORIGIN")
"""The SITL's truth and the local origin (companion/link/truth.py), read as raw MAVLink: MAVSDK's
plugins carry neither."""
AUTOPILOT_COMPONENT = 1  # MAV_COMP_ID_AUTOPILOT1

mavsdk_log = logging.getLogger("mavsdk")

# MAVSDK FlightMode / LandedState names -> the PX4 / MAVLink names VehicleSnapshot uses
FLIGHT_MODES = {
    "READY": "AUTO.READY", "TAKEOFF": "AUTO.TAKEOFF", "HOLD": "AUTO.LOITER",
    "MISSION": "AUTO.MISSION", "RETURN_TO_LAUNCH": "AUTO.RTL", "LAND": "AUTO.LAND",
    "FOLLOW_ME": "AUTO.FOLLOW_TARGET", "OFFBOARD": "OFFBOARD", "MANUAL": "MANUAL",
    "ALTCTL": "ALTCTL", "POSCTL": "POSCTL", "ACRO": "ACRO", "STABILIZED": "STABILIZED",
    "RATTITUDE": "RATTITUDE",
}  # fmt: skip
LANDED = {"UNKNOWN": "UNDEFINED", "TAKING_OFF": "TAKEOFF"}
# MAVSDK result names -> MAV_RESULT names, so callers see one vocabulary
RESULTS = {"COMMAND_DENIED": "DENIED", "BUSY": "TEMPORARILY_REJECTED"}
LOST_RESULTS = {"NO_SYSTEM", "CONNECTION_ERROR"}
URL_SCHEMES = {"tcp": "tcpout"}  # ours -> MAVSDK's, where they differ


def mavsdk_url(connection: str, baud: int) -> str:
    """MAVSDK's URL for a MAVLink-tools connection string (udpin:H:P -> udpin://H:P ...)."""
    spec = parse_connection(connection, baud)
    if spec.kind == "serial":
        return f"serial://{spec.device}:{spec.baud}"
    scheme, rest = spec.device.split(":", 1)
    return f"{URL_SCHEMES.get(scheme, scheme)}://{rest}"


def route_mavsdk_log() -> None:
    """Send MAVSDK's own log to Python logging (it prints to stdout otherwise)."""
    from mavsdk import LogLevel, log_subscribe

    levels = {LogLevel.DEBUG: logging.DEBUG, LogLevel.INFO: logging.INFO,
              LogLevel.WARN: logging.WARNING, LogLevel.ERROR: logging.ERROR}  # fmt: skip

    def forward(level: Any, message: str, _file: str | None, _line: int) -> bool:
        mavsdk_log.log(levels.get(level, logging.INFO), "%s", message)
        return True

    log_subscribe(forward)


def translate_result(what: str, result: str) -> Exception:
    """The companion error for a MAVSDK result name that is not SUCCESS."""
    if result == "TIMEOUT":
        return LinkTimeout(f"{what}: the vehicle did not answer (MAVSDK TIMEOUT)")
    if result in LOST_RESULTS:
        return LinkLost(f"{what}: MAVSDK reports {result}; check the connection")
    return CommandRejected(
        what,
        RESULTS.get(result, result),
        "read the vehicle's status messages, fix the cause and retry",
    )


def initial_snapshot(system_id: int, autopilot: str, now_s: float) -> VehicleSnapshot:
    zero = (0.0, 0.0, 0.0)
    return VehicleSnapshot(
        received_s=now_s, time_boot_ms=0, frame_time_boot_ms=None, system_id=system_id,
        autopilot=autopilot, armed=False, mode="UNKNOWN", landed_state="UNDEFINED",
        position_ned_m=zero, velocity_ned_m_s=zero, attitude_rad=zero, rates_frd_rad_s=zero,
        heartbeat_s=now_s,
    )  # fmt: skip


def fold_direct_telemetry(s: VehicleSnapshot, message: Any) -> VehicleSnapshot:
    """LOCAL_POSITION_NED or ATTITUDE as MavlinkDirect hands it over (its fields as JSON),
    folded by the pymavlink link's own rules (companion/link/telemetry.py): both links carry
    the vehicle's own stamp of each message, and values never mix with another message's
    stamp. ATTITUDE marks a frame (``wait_frame``). ValueError for a malformed or non-finite
    message, or one from another component than the autopilot."""
    if int(message.component_id) != AUTOPILOT_COMPONENT:
        raise ValueError(f"{message.message_name} from component {message.component_id}, not the autopilot")
    fields = json.loads(message.fields_json)
    kind = fields.get("message_name") if isinstance(fields, dict) else None
    if kind not in DIRECT_TELEMETRY:
        raise ValueError(f"not a telemetry message the link folds: {kind!r}")
    try:
        changes = HANDLERS[kind](SimpleNamespace(**fields), 0.0)
    except (AttributeError, TypeError) as exc:
        raise ValueError(f"{kind} without its fields: {exc}") from None
    if kind == "ATTITUDE":
        changes["frame_time_boot_ms"] = changes["time_boot_ms"]
    return with_changes(s, changes)


class _DirectMessage(SimpleNamespace):
    """A MavlinkDirect message's fields, shaped as a pymavlink message for the shared folding rules."""

    def get_type(self) -> str:
        return str(self.message_name)


def fold_direct_truth(s: VehicleSnapshot, message: Any) -> VehicleSnapshot:
    """HIL_STATE_QUATERNION, SIM_STATE or GPS_GLOBAL_ORIGIN as MavlinkDirect hands it over,
    folded by the pymavlink link's own rules (the true pose, the origin); ValueError for a
    malformed or non-finite one, or one from another component than the autopilot."""
    if int(message.component_id) != AUTOPILOT_COMPONENT:
        raise ValueError(f"{message.message_name} from component {message.component_id}, not the autopilot")
    fields = json.loads(message.fields_json)
    if not isinstance(fields, dict) or fields.get("message_name") not in DIRECT_TRUTH:
        raise ValueError(f"not a truth message the link folds: {message.message_name!r}")
    try:
        return apply_message(s, _DirectMessage(**fields), time.monotonic(), frame_marker="")
    except (AttributeError, TypeError) as exc:
        raise ValueError(f"{fields['message_name']} without its fields: {exc}") from None


def fold_flight_mode(s: VehicleSnapshot, mode: Any) -> VehicleSnapshot:
    return replace(s, mode=FLIGHT_MODES.get(mode.name, mode.name), heartbeat_s=time.monotonic())


def fold_landed_state(s: VehicleSnapshot, state: Any) -> VehicleSnapshot:
    return replace(s, landed_state=LANDED.get(state.name, state.name))
