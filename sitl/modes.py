"""PX4 flight modes as MAVLink encodes them, and the rules for switching between them.

PX4 packs its mode into HEARTBEAT.custom_mode as ``main << 16 | sub << 24``; MAVSDK,
QGroundControl and MAVProxy decode it that way when the autopilot type is PX4.
"""

from __future__ import annotations

from enum import Enum


class Mode(Enum):
    """The modes the SITL flies, with their PX4 (main, sub) mode numbers."""

    MANUAL = (1, 0)
    ALTCTL = (2, 0)
    POSCTL = (3, 0)
    AUTO_TAKEOFF = (4, 2)
    AUTO_LOITER = (4, 3)
    AUTO_LAND = (4, 6)
    AUTO_PRECLAND = (4, 9)
    OFFBOARD = (6, 0)

    @property
    def custom_mode(self) -> int:
        main, sub = self.value
        return (main << 16) | (sub << 24)

    @property
    def px4_name(self) -> str:
        return self.name.replace("_", ".")

    @classmethod
    def from_custom_mode(cls, custom_mode: int) -> Mode:
        main = (int(custom_mode) >> 16) & 0xFF
        sub = (int(custom_mode) >> 24) & 0xFF
        return cls.from_main_sub(main, sub)

    @classmethod
    def from_main_sub(cls, main: int, sub: int) -> Mode:
        """Decode PX4 (main, sub); AUTO with sub 0 means LOITER as PX4 treats it."""
        if main == 4 and sub == 0:
            sub = 3
        for mode in cls:
            if mode.value == (main, sub):
                return mode
        raise ValueError(f"unsupported PX4 mode main={main} sub={sub}")


# Modes a person or companion may ask for (MANUAL/ALTCTL are mapped to POSCTL's
# position-assisted flight, as the SITL has no stick-to-attitude mode).
SUPPORTED = frozenset(Mode)


def refusal(target: Mode, *, armed: bool, landed: bool, setpoints_fresh: bool) -> str | None:
    """Why switching to ``target`` is refused now, or None if it is allowed (PX4's rules)."""
    if target is Mode.OFFBOARD and not setpoints_fresh:
        return "OFFBOARD refused: stream setpoints first (none received recently)"
    if target in (Mode.AUTO_LAND, Mode.AUTO_PRECLAND) and landed and not armed:
        return "already landed"
    return None
