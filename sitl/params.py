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


@dataclass(frozen=True)
class Binding:
    """A PX4 parameter that is a field of AutopilotConfig (``scale``: config unit -> PX4 unit)."""

    name: str
    field: str
    minimum: float
    maximum: float
    scale: float = 1.0


DEG = math.degrees(1.0)
BINDINGS: tuple[Binding, ...] = (
    Binding("MPC_XY_VEL_MAX", "max_speed_xy_m_s", 0.1, 20.0),
    Binding("MPC_Z_VEL_MAX_UP", "max_speed_up_m_s", 0.1, 8.0),
    Binding("MPC_Z_VEL_MAX_DN", "max_speed_down_m_s", 0.1, 4.0),
    Binding("MPC_TILTMAX_AIR", "max_tilt_rad", 5.0, 65.0, DEG),
    Binding("MPC_MAN_Y_MAX", "max_yaw_rate_rad_s", 1.0, 400.0, DEG),
    Binding("MPC_LAND_SPEED", "land_speed_m_s", 0.1, 3.0),
    Binding("MIS_TAKEOFF_ALT", "takeoff_alt_m", 0.5, 100.0),
    Binding("COM_OF_LOSS_T", "offboard_loss_hold_s", 0.05, 60.0),
    Binding("COM_OBL_LAND_T", "offboard_loss_land_s", 0.1, 600.0),
    Binding("MPC_XY_P", "pos_p_xy", 0.0, 5.0),
    Binding("MPC_Z_P", "pos_p_z", 0.0, 5.0),
    Binding("MPC_XY_VEL_P_ACC", "vel_p_xy", 0.0, 20.0),
    Binding("MPC_XY_VEL_I_ACC", "vel_i_xy", 0.0, 20.0),
    Binding("MPC_Z_VEL_P_ACC", "vel_p_z", 0.0, 20.0),
    Binding("MPC_Z_VEL_I_ACC", "vel_i_z", 0.0, 20.0),
    Binding("MC_ROLL_P", "att_p_rp", 0.0, 20.0),
    Binding("MC_YAW_P", "att_p_yaw", 0.0, 10.0),
    Binding("MC_ROLLRATE_P", "rate_p_rp", 0.0, 1.0),
    Binding("MC_ROLLRATE_I", "rate_i_rp", 0.0, 2.0),
    Binding("MC_ROLLRATE_D", "rate_d_rp", 0.0, 0.1),
    Binding("MC_YAWRATE_P", "rate_p_yaw", 0.0, 2.0),
    Binding("MC_YAWRATE_I", "rate_i_yaw", 0.0, 2.0),
    Binding("MPC_THR_HOVER", "hover_throttle", 0.1, 0.8),
)
# PX4's multicopter land detector, listed (after the identity parameters: the others keep their
# indices) only with ``land_detector = "px4"``: the "contact" rule has none, and its parameter
# list stays what it was before these existed
LAND_BINDINGS: tuple[Binding, ...] = (
    Binding("LNDMC_Z_VEL_MAX", "land_z_vel_max_m_s", 0.01, 5.0),
    Binding("LNDMC_XY_VEL_MAX", "land_xy_vel_max_m_s", 0.1, 10.0),
    Binding("LNDMC_ROT_MAX", "land_rot_max_deg_s", 1.0, 360.0),
    Binding("LNDMC_TRIG_TIME", "land_trigger_time_s", 0.1, 10.0),
)
ALL_BINDINGS = BINDINGS + LAND_BINDINGS
BINDING_BY_NAME = {b.name: b for b in ALL_BINDINGS}


def _bound(cfg: AutopilotConfig, bindings: tuple[Binding, ...]) -> list[Param]:
    return [Param(b.name, getattr(cfg, b.field) * b.scale, REAL32, b.minimum, b.maximum) for b in bindings]


def autopilot_params(cfg: AutopilotConfig) -> list[Param]:
    """PX4-named parameters for the limits, gains and failsafes the SITL's autopilot honours."""
    return _bound(cfg, BINDINGS) + [
        Param("COM_DISARM_LAND", 2.0, REAL32, -1.0, 20.0),
        Param("MAV_SYS_ID", 1, INT32, 1, 255),
        Param("MAV_TYPE", mavlink.MAV_TYPE_QUADROTOR, INT32, 0, 50),
        Param("SYS_AUTOSTART", 4001, INT32, 0, 9_999_999),
    ] + _bound(cfg, land_bindings(cfg)) + precland_params()


def precland_params() -> list[Param]:
    """PX4's precision landing (PLD_*) and landing target estimator (LTEST_*) parameters, with
    PX4's defaults; listed last, so the others keep their indices."""
    from sitl.px4_precland import INT_PARAMS, PX4_LTEST_DEFAULTS, PX4_PRECLAND_DEFAULTS

    ranges = {"PLD_MAX_SRCH": (0, 100), "LTEST_MODE": (0, 1), "LTEST_ACC_UNC": (0.01, math.inf),
              "LTEST_POS_UNC_IN": (0.001, math.inf), "LTEST_VEL_UNC_IN": (0.001, math.inf),
              "LTEST_SCALE_X": (0.01, math.inf), "LTEST_SCALE_Y": (0.01, math.inf)}
    return [Param(name, value, INT32 if name in INT_PARAMS else REAL32, *ranges.get(name, (0.0, math.inf)))
            for name, value in (PX4_PRECLAND_DEFAULTS | PX4_LTEST_DEFAULTS).items()]


def land_bindings(cfg: AutopilotConfig) -> tuple[Binding, ...]:
    """The LNDMC_* parameters this config's land detector has (none for "contact")."""
    return LAND_BINDINGS if cfg.land_detector == "px4" else ()


def apply_to_config(cfg: AutopilotConfig, store: ParamStore) -> AutopilotConfig:
    """The autopilot config with every bound parameter's current value."""
    update = {b.field: store.get(b.name) / b.scale for b in BINDINGS + land_bindings(cfg)}
    return cfg.model_copy(update=update)


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
