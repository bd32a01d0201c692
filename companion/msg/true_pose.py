"""The true pose: where a simulator says the vehicle is, beside the autopilot's estimate.

Only an autopilot's SITL sends one (PX4 SIH: HIL_STATE_QUATERNION; ArduPilot: SIM_STATE),
never a real vehicle; companion/link/truth.py makes it, the telemetry folds it into the
snapshot, and the rendered camera draws from it (companion/vision/rendered.py).
"""

from __future__ import annotations

from dataclasses import dataclass

from companion.msg.checks import finite_real

Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class TruePose:
    """The simulator's true position in the vehicle's local frame (north, east, down of the
    local origin, GPS_GLOBAL_ORIGIN, down from the origin's altitude) and its true attitude."""

    north_m: float
    east_m: float
    down_m: float
    attitude_rad: Vec3  # roll, pitch, yaw
    time_boot_ms: int  # the vehicle's clock at the truth (see companion/link/truth.py per autopilot)
    source: str  # the message it came from: "HIL_STATE_QUATERNION", "SIM_STATE"
    received_s: float  # monotonic time it arrived, for the staleness rule

    def __post_init__(self) -> None:
        hint = "drop the message: a simulator's truth is never non-finite"
        for name in ("north_m", "east_m", "down_m", "received_s"):
            finite_real("TruePose", name, getattr(self, name), hint)
        if len(self.attitude_rad) != 3:
            raise ValueError(f"TruePose.attitude_rad must be (roll, pitch, yaw), got {self.attitude_rad!r}")
        for i, value in enumerate(self.attitude_rad):
            finite_real("TruePose", f"attitude_rad[{i}]", value, hint)
        if isinstance(self.time_boot_ms, bool) or not isinstance(self.time_boot_ms, int) or self.time_boot_ms < 0:
            raise ValueError(f"TruePose.time_boot_ms must be an int >= 0, got {self.time_boot_ms!r}")
        if not self.source:
            raise ValueError("TruePose.source must name the message the truth came from")

    @property
    def position_ned_m(self) -> Vec3:
        return (self.north_m, self.east_m, self.down_m)
