"""MANUAL_CONTROL from a ground station, checked before a human-input source sees it.

MAVLink defines x = pitch (forward +), y = roll (right +), z = thrust, r = yaw (clockwise +),
each in -1000..1000 (QGroundControl and MAVProxy send thrust 0..1000), and ``INT16_MAX``
for an axis that is not in use. Values outside that range mean a broken sender: the whole
message is dropped (and counted by the link) rather than clamped, so garbage never steers.
What passes is handed on in MAVLink's own units (a mapping of field name to value), so the
input source decides the mapping (throttle range, override button) from its config.
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass
from typing import Any

log = logging.getLogger(__name__)

AXIS_LIMIT = 1000
AXIS_UNUSED = 32767  # INT16_MAX: "this axis is invalid/unused"
AXES = ("x", "y", "z", "r")


@dataclass(frozen=True)
class ManualControlMessage(Mapping[str, int]):
    """One checked MANUAL_CONTROL: raw axes in -1000..1000 or AXIS_UNUSED, 32 button bits.

    It also reads as a mapping of its MAVLink fields (``msg["x"]``, ``msg.get("buttons2")``),
    so code written for pymavlink's ``msg.to_dict()`` takes it as it is.
    """

    x: int
    y: int
    z: int
    r: int
    buttons: int  # bit i = button i held; bits 16..31 come from MAVLink 2's buttons2
    target_system: int
    source_system: int
    source_component: int
    received_s: float  # monotonic

    def __post_init__(self) -> None:
        for name in AXES:
            value = getattr(self, name)
            if value != AXIS_UNUSED and not -AXIS_LIMIT <= value <= AXIS_LIMIT:
                raise ValueError(f"MANUAL_CONTROL {name}={value} outside -1000..1000")

    def axis(self, name: str) -> float | None:
        """Axis ``name`` ("x", "y", "z", "r") scaled to [-1, 1]; None when not in use."""
        raw = getattr(self, name)
        return None if raw == AXIS_UNUSED else raw / AXIS_LIMIT

    def pressed(self, button: int) -> bool:
        """Whether button number ``button`` (0-31) is held."""
        return bool(self.buttons >> button & 1)

    def fields(self) -> dict[str, int]:
        """The message's fields by MAVLink name (for ``inputs.ManualControlInput.feed``)."""
        return {
            "x": self.x, "y": self.y, "z": self.z, "r": self.r,
            "buttons": self.buttons & 0xFFFF, "buttons2": self.buttons >> 16,
            "target": self.target_system,
        }  # fmt: skip

    def __getitem__(self, key: str) -> int:
        return self.fields()[key]

    def __iter__(self) -> Iterator[str]:
        return iter(FIELD_NAMES)

    def __len__(self) -> int:
        return len(FIELD_NAMES)


FIELD_NAMES = ("x", "y", "z", "r", "buttons", "buttons2", "target")


def manual_control_from_fields(
    fields: Mapping[str, Any], source_system: int, source_component: int, received_s: float
) -> ManualControlMessage | None:
    """The checked message from its field values, or None if an axis is out of range."""
    try:
        x, y, z, r = (int(fields[name]) for name in AXES)
        buttons = int(fields.get("buttons", 0)) & 0xFFFF
        buttons |= (int(fields.get("buttons2", 0) or 0) & 0xFFFF) << 16
        return ManualControlMessage(
            x=x,
            y=y,
            z=z,
            r=r,
            buttons=buttons,
            target_system=int(fields.get("target", 0)),
            source_system=source_system,
            source_component=source_component,
            received_s=received_s,
        )
    except (KeyError, TypeError, ValueError):
        return None


def parse_manual_control(msg: Any, received_s: float) -> ManualControlMessage | None:
    """The checked message of a pymavlink MANUAL_CONTROL, or None if it is out of range."""
    return manual_control_from_fields(
        msg.to_dict(), msg.get_srcSystem(), msg.get_srcComponent(), received_s
    )


def addressed_to_us(target: int, companion_system: int, vehicle_system: int | None) -> bool:
    """Whether a MANUAL_CONTROL for system ``target`` is ours to take: sent to all (0), to the
    companion, or to the vehicle it flies (``vehicle_system``; None: none adopted yet)."""
    return target in (0, companion_system) or target == vehicle_system


def deliver_manual_control(value: ManualControlMessage | None, sender: int, counts: Counter[str],
                           callback: Callable[[ManualControlMessage], None] | None) -> None:
    """A link's last step with a MANUAL_CONTROL of system ``sender``: out of range (None) it is
    dropped, counted and logged; else handed to ``callback`` (if any), whose failure is counted
    and logged, never the end of the link's thread."""
    if value is None:
        counts["manual_control_dropped"] += 1
        log.warning("MANUAL_CONTROL from %d with out-of-range axes dropped", sender)
        return
    if callback is None:
        return
    try:
        callback(value)
    except Exception:  # noqa: BLE001 - a faulty consumer must not kill the link
        counts["callback_errors"] += 1
        log.exception("manual-control callback failed")
