"""MANUAL_CONTROL from a ground station, checked and normalised for a human-input source.

MAVLink defines x = pitch (forward +), y = roll (right +), z = thrust, r = yaw (clockwise +),
each in -1000..1000 (QGroundControl and MAVProxy send thrust 0..1000), and ``INT16_MAX``
for an axis that is not in use. Values outside that range mean a broken sender: the whole
message is dropped (and counted by the link) rather than clamped, so garbage never steers.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

AXIS_LIMIT = 1000
AXIS_UNUSED = 32767  # INT16_MAX: "this axis is invalid/unused"


@dataclass(frozen=True)
class ManualControlInput:
    """One MANUAL_CONTROL message; axes scaled to [-1, 1], ``None`` when the sender marks it unused."""

    x: float | None
    y: float | None
    z: float | None
    r: float | None
    buttons: int  # bit i = button i pressed; buttons 16..31 come from MAVLink 2's buttons2
    target_system: int
    source_system: int
    source_component: int
    received_s: float  # monotonic

    def pressed(self, button: int) -> bool:
        """Whether button number ``button`` (0-based) is held."""
        return bool(self.buttons >> button & 1)


def _axis(raw: int) -> float | None:
    if raw == AXIS_UNUSED:
        return None
    if not -AXIS_LIMIT <= raw <= AXIS_LIMIT:
        raise ValueError(raw)
    return raw / AXIS_LIMIT


def manual_control_from_fields(
    fields: Mapping[str, Any], source_system: int, source_component: int, received_s: float
) -> ManualControlInput | None:
    """The checked input of MANUAL_CONTROL given as field values, or None if out of range."""
    try:
        axes = [_axis(int(fields[name])) for name in ("x", "y", "z", "r")]
    except ValueError:
        return None
    buttons = int(fields.get("buttons", 0)) & 0xFFFF
    buttons |= (int(fields.get("buttons2", 0) or 0) & 0xFFFF) << 16
    return ManualControlInput(
        *axes,
        buttons=buttons,
        target_system=int(fields.get("target", 0)),
        source_system=source_system,
        source_component=source_component,
        received_s=received_s,
    )


def parse_manual_control(msg: Any, received_s: float) -> ManualControlInput | None:
    """The checked input of a pymavlink MANUAL_CONTROL message, or None if out of range."""
    return manual_control_from_fields(
        msg.to_dict(), msg.get_srcSystem(), msg.get_srcComponent(), received_s
    )
