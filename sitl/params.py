"""The vehicle's parameter set, served over MAVLink's parameter protocol.

PX4 advertises MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE: an INT32 parameter travels in
PARAM_VALUE's float field as the same four bytes, not as a converted number.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass

from pymavlink.dialects.v20 import common as mavlink

from sitl.config import AutopilotConfig

INT32 = mavlink.MAV_PARAM_TYPE_INT32
REAL32 = mavlink.MAV_PARAM_TYPE_REAL32


@dataclass
class Param:
    name: str
    value: float
    kind: int  # MAV_PARAM_TYPE_*
    minimum: float = -math.inf
    maximum: float = math.inf


def encode_value(value: float, kind: int) -> float:
    """The float that goes on the wire for ``value`` (bytewise for integers)."""
    if kind == INT32:
        return float(struct.unpack("<f", struct.pack("<i", int(value)))[0])
    return float(value)


def decode_value(wire: float, kind: int) -> float:
    """Inverse of :func:`encode_value`."""
    if kind == INT32:
        return float(struct.unpack("<i", struct.pack("<f", wire))[0])
    return float(wire)


def autopilot_params(cfg: AutopilotConfig) -> list[Param]:
    """PX4-named parameters for the limits and failsafes the SITL's autopilot honours."""
    return [
        Param("MPC_XY_VEL_MAX", cfg.max_speed_xy_m_s, REAL32, 0.1, 20.0),
        Param("MPC_Z_VEL_MAX_UP", cfg.max_speed_up_m_s, REAL32, 0.1, 8.0),
        Param("MPC_Z_VEL_MAX_DN", cfg.max_speed_down_m_s, REAL32, 0.1, 4.0),
        Param("MPC_TILTMAX_AIR", math.degrees(cfg.max_tilt_rad), REAL32, 5.0, 65.0),
        Param("MPC_MAN_Y_MAX", math.degrees(cfg.max_yaw_rate_rad_s), REAL32, 1.0, 400.0),
        Param("MPC_LAND_SPEED", cfg.land_speed_m_s, REAL32, 0.1, 3.0),
        Param("MIS_TAKEOFF_ALT", cfg.takeoff_alt_m, REAL32, 0.5, 100.0),
        Param("COM_OF_LOSS_T", cfg.offboard_loss_hold_s, REAL32, 0.05, 60.0),
        Param("COM_OBL_LAND_T", cfg.offboard_loss_land_s, REAL32, 0.0, 600.0),
        Param("COM_DISARM_LAND", 2.0, REAL32, -1.0, 20.0),
        Param("MAV_SYS_ID", 1, INT32, 1, 255),
        Param("MAV_TYPE", mavlink.MAV_TYPE_QUADROTOR, INT32, 0, 50),
        Param("SYS_AUTOSTART", 4001, INT32, 0, 9_999_999),
    ]


class ParamStore:
    """Ordered parameters with index lookup; sets are clamped to the parameter's range."""

    def __init__(self, params: list[Param]) -> None:
        self._params = list(params)
        self._index = {p.name: i for i, p in enumerate(self._params)}

    def __len__(self) -> int:
        return len(self._params)

    def __iter__(self):  # type: ignore[no-untyped-def]
        return iter(self._params)

    def get(self, name: str) -> float:
        return self._params[self._index[name]].value

    def index_of(self, name: str) -> int:
        return self._index[name]

    def by_index(self, index: int) -> Param | None:
        return self._params[index] if 0 <= index < len(self._params) else None

    def by_name(self, name: str) -> Param | None:
        i = self._index.get(name)
        return None if i is None else self._params[i]

    def set(self, name: str, wire_value: float, kind: int | None = None) -> Param | None:
        """Apply a PARAM_SET; returns the parameter as stored, or None if unknown or non-finite."""
        param = self.by_name(name)
        if param is None:
            return None
        value = decode_value(wire_value, param.kind if kind is None else kind)
        if not math.isfinite(value):
            return param
        param.value = min(max(value, param.minimum), param.maximum)
        if param.kind == INT32:
            param.value = float(int(param.value))
        return param
