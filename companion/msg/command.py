"""The joystick command: what people and policies produce and what the dataset records."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields

import numpy as np

from companion.msg.checks import finite_real

AXES = ("roll", "pitch", "yaw", "throttle")
"""The order of a command as an array: the policy's output and the dataset's action columns."""


@dataclass(frozen=True)
class JoystickCommand:
    """Stick positions in [-1, 1]: roll +1 = move right, pitch +1 = forward,
    yaw +1 = turn clockwise, throttle +1 = climb."""

    roll: float
    pitch: float
    yaw: float
    throttle: float

    def __post_init__(self) -> None:
        for f in fields(self):
            value = finite_real("JoystickCommand", f.name, getattr(self, f.name),
                                "pass untrusted values through commands.sanitize()")
            if not -1.0 <= value <= 1.0:
                raise ValueError(
                    f"JoystickCommand.{f.name} must be in [-1, 1], got {value!r}; "
                    "pass untrusted values through commands.sanitize()"
                )
            object.__setattr__(self, f.name, value)

    @classmethod
    def neutral(cls) -> JoystickCommand:
        """Sticks centred: hover in place (throttle 0 = hold altitude)."""
        return cls(0.0, 0.0, 0.0, 0.0)

    @classmethod
    def from_array(cls, values: Sequence[float] | np.ndarray) -> JoystickCommand:
        """Strict construction from four values in :data:`AXES` order (raises on bad values)."""
        arr = four_values(values)
        return cls(*(float(v) for v in arr))

    def to_array(self) -> np.ndarray:
        """The four values in :data:`AXES` order as float64."""
        return np.array([self.roll, self.pitch, self.yaw, self.throttle], dtype=np.float64)


def four_values(values: Sequence[float] | np.ndarray) -> np.ndarray:
    arr = np.asarray(values, dtype=np.float64).reshape(-1)
    if arr.shape != (4,):
        raise ValueError(
            f"a joystick command has 4 values ({', '.join(AXES)}), got {arr.size}; "
            "check the policy's output size"
        )
    return arr


ACTION_NAMES: tuple[str, ...] = AXES
"""The action columns: a command's values in :data:`AXES` order."""
ACT_DIM = len(ACTION_NAMES)
