"""Setpoints handed from the commands module to the link.

A setpoint is a frozen value that refuses non-finite numbers when it is made, so that nothing
downstream (the link, the vehicle) ever has to wonder whether a NaN slipped through. Range
limits belong to the commands module (which clips) and to the link (which refuses).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

from companion.msg.checks import finite_real


@dataclass(frozen=True)
class VelocitySetpoint:
    """A velocity and yaw-rate demand in the body frame (FRD), as MAVSDK's VelocityBodyYawspeed.

    ``down_m_s`` is positive downwards; ``yaw_rate_rad_s`` positive turns clockwise seen from
    above.
    """

    forward_m_s: float
    right_m_s: float
    down_m_s: float
    yaw_rate_rad_s: float

    def __post_init__(self) -> None:
        for f in fields(self):
            value = finite_real("VelocitySetpoint", f.name, getattr(self, f.name),
                                "only finite values may be sent to the vehicle - drop or clamp the command "
                                "before building a setpoint")
            object.__setattr__(self, f.name, value)

    @classmethod
    def zero(cls) -> VelocitySetpoint:
        """Hover in place without turning."""
        return cls(0.0, 0.0, 0.0, 0.0)

    def as_tuple(self) -> tuple[float, float, float, float]:
        return (self.forward_m_s, self.right_m_s, self.down_m_s, self.yaw_rate_rad_s)
