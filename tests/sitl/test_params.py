"""Parameter store and PX4's bytewise encoding of integer parameters."""

import math

import pytest

from sitl.config import AutopilotConfig
from sitl.params import INT32, REAL32, ParamStore, autopilot_params, decode_value, encode_value


def test_int32_travels_bytewise_in_the_float_field() -> None:
    wire = encode_value(4001, INT32)
    assert wire != 4001.0  # the bits, not the number
    assert decode_value(wire, INT32) == 4001
    assert encode_value(2.5, REAL32) == 2.5


def test_store_reflects_config_and_clamps_sets() -> None:
    store = ParamStore(autopilot_params(AutopilotConfig(takeoff_alt_m=3.0)))
    assert store.get("MIS_TAKEOFF_ALT") == 3.0
    store.set("MIS_TAKEOFF_ALT", 1e6)
    assert store.get("MIS_TAKEOFF_ALT") == 100.0  # the parameter's maximum
    assert store.set("NO_SUCH_PARAM", 1.0) is None


def test_non_finite_set_is_ignored() -> None:
    store = ParamStore(autopilot_params(AutopilotConfig()))
    before = store.get("COM_OF_LOSS_T")
    store.set("COM_OF_LOSS_T", math.nan)
    assert store.get("COM_OF_LOSS_T") == before


def test_integer_param_set_bytewise() -> None:
    store = ParamStore(autopilot_params(AutopilotConfig()))
    store.set("MAV_SYS_ID", encode_value(7, INT32), INT32)
    assert store.get("MAV_SYS_ID") == 7


def test_every_bound_parameter_starts_at_its_config_value() -> None:
    from sitl.params import BINDINGS, apply_to_config

    cfg = AutopilotConfig()
    store = ParamStore(autopilot_params(cfg))
    assert len(BINDINGS) >= 20  # limits, failsafes and the cascade's gains
    assert apply_to_config(cfg, store) == cfg
    assert store.get("MPC_TILTMAX_AIR") == pytest.approx(math.degrees(cfg.max_tilt_rad))


def test_a_gain_set_by_parameter_reaches_the_config() -> None:
    from sitl.params import apply_to_config

    cfg = AutopilotConfig()
    store = ParamStore(autopilot_params(cfg))
    store.set("MPC_XY_VEL_P_ACC", 2.0)
    store.set("MPC_TILTMAX_AIR", 30.0)
    new = apply_to_config(cfg, store)
    assert new.vel_p_xy == 2.0 and new.max_tilt_rad == pytest.approx(math.radians(30.0))
