"""Parameter store and PX4's bytewise encoding of integer parameters."""

import math

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
