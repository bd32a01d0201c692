"""PX4 flight modes as MAVLink carries them: ``custom_mode = main << 16 | sub << 24``.

Names follow PX4's own (``OFFBOARD``, ``AUTO.LOITER``); a few short aliases that people and
other tools use (``HOLD``, ``LAND``) are accepted when asking for a mode.
"""

from __future__ import annotations

from companion.errors import CommandRejected

# name -> (main mode, sub mode)
PX4_MODES: dict[str, tuple[int, int]] = {
    "MANUAL": (1, 0),
    "ALTCTL": (2, 0),
    "POSCTL": (3, 0),
    "AUTO.READY": (4, 1),
    "AUTO.TAKEOFF": (4, 2),
    "AUTO.LOITER": (4, 3),
    "AUTO.MISSION": (4, 4),
    "AUTO.RTL": (4, 5),
    "AUTO.LAND": (4, 6),
    "AUTO.FOLLOW_TARGET": (4, 8),
    "AUTO.PRECLAND": (4, 9),
    "ACRO": (5, 0),
    "OFFBOARD": (6, 0),
    "STABILIZED": (7, 0),
}

ALIASES: dict[str, str] = {
    "HOLD": "AUTO.LOITER",
    "LOITER": "AUTO.LOITER",
    "LAND": "AUTO.LAND",
    "TAKEOFF": "AUTO.TAKEOFF",
    "RTL": "AUTO.RTL",
    "MISSION": "AUTO.MISSION",
    "POSITION": "POSCTL",
    "ALTITUDE": "ALTCTL",
}

_BY_CUSTOM_MODE = {main << 16 | sub << 24: name for name, (main, sub) in PX4_MODES.items()}


def canonical_name(name: str) -> str:
    """The PX4 name for ``name`` (case-insensitive, aliases resolved)."""
    upper = name.strip().upper()
    upper = ALIASES.get(upper, upper)
    if upper not in PX4_MODES:
        raise CommandRejected(
            f"set_mode({name!r})",
            "UNSUPPORTED",
            f"unknown PX4 mode; use one of {sorted(PX4_MODES)} or {sorted(ALIASES)}",
            origin="companion",
        )
    return upper


def encode(name: str) -> tuple[int, int]:
    """(main, sub) of a mode name, for MAV_CMD_DO_SET_MODE's param2 and param3."""
    return PX4_MODES[canonical_name(name)]


def custom_mode(name: str) -> int:
    """The HEARTBEAT ``custom_mode`` value of a mode name."""
    main, sub = encode(name)
    return main << 16 | sub << 24


def decode(custom: int) -> str:
    """The PX4 name of a HEARTBEAT ``custom_mode``; unknown values read ``UNKNOWN(<hex>)``."""
    custom &= 0xFFFF0000
    if custom in _BY_CUSTOM_MODE:
        return _BY_CUSTOM_MODE[custom]
    main = (custom >> 16) & 0xFF
    if main and custom >> 24 == 0 and (main << 16) in _BY_CUSTOM_MODE:
        return _BY_CUSTOM_MODE[main << 16]
    return f"UNKNOWN(0x{custom:08x})"
