"""The link to the vehicle: one interface (:class:`VehicleLink`), two backends.

``open_link(cfg)`` gives the pymavlink backend (any MAVLink autopilot, lockstep-aware);
``open_link(cfg, "mavsdk")`` the MAVSDK one (PX4, real time only). See docs/link.md.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from companion import install_hint
from companion.config import LinkConfig
from companion.errors import ConfigError
from companion.link.base import LinkStats, SetpointLimits, VehicleLink
from companion.link.manual_control import ManualControlMessage
from companion.msg.setpoint import VelocitySetpoint
from companion.msg.snapshot import VehicleSnapshot

LinkKind = Literal["pymavlink", "mavsdk"]

__all__ = [
    "LinkStats",
    "ManualControlMessage",
    "SetpointLimits",
    "VehicleLink",
    "VehicleSnapshot",
    "VelocitySetpoint",
    "open_link",
]


def open_link(
    cfg: LinkConfig, kind: LinkKind = "pymavlink", tlog_path: str | Path | None = None
) -> VehicleLink:
    """A new, not yet connected link of the given backend; call ``connect()`` next."""
    if kind == "pymavlink":
        from companion.link.mavlink_link import MavlinkLink

        return MavlinkLink(cfg, tlog_path=tlog_path)
    if kind == "mavsdk":
        from companion.link.mavsdk_link import MavsdkLink

        _require_mavsdk()
        return MavsdkLink(cfg, tlog_path=tlog_path)
    raise ConfigError(f"unknown link kind {kind!r}; use 'pymavlink' or 'mavsdk'")


def _require_mavsdk() -> None:
    """The MAVSDK backend is an extra; say how to get it before connecting fails deep inside."""
    import importlib.util

    if importlib.util.find_spec("mavsdk") is None:
        raise ConfigError(f"the MAVSDK link needs the mavsdk extra: {install_hint('mavsdk')}")
