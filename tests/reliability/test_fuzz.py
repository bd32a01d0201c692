"""Fuzzing: property tests of every parser (hypothesis), then a short bounded run of hostile UDP
at a running SITL and at the companion's link (bench/faults.py sends >= 100,000 to each)."""

from __future__ import annotations

import logging
import math
from functools import cache

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pymavlink.dialects.v20 import common as M

from colcommon.errors import ConfigError
from colcommon.signing import parse_key
from companion.link.manual_control import parse_manual_control
from companion.link.telemetry import InvalidTelemetry, apply_message, initial_snapshot
from companion.testing.fuzz import KINDS, packets
from companion.testing.fuzz_targets import fuzz_link, fuzz_sitl
from sitl.config import SitlConfig
from sitl.handler import MessageHandler
from sitl.telemetry import TelemetryScheduler
from sitl.transports import MavClient
from sitl.vehicle import SimVehicle

PROPERTY = settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
floats = st.floats(allow_nan=True, allow_infinity=True, width=32)
any_float = st.one_of(floats, st.sampled_from([math.nan, math.inf, -math.inf, 3.4e38, -3.4e38]))


class _Parser(MavClient):
    name = "fuzz"


@cache
def grounded_handler() -> MessageHandler:
    """One SITL vehicle on the ground, disarmed (JSBSim is loaded once for the module)."""
    v = SimVehicle(SitlConfig())
    return MessageHandler(v, TelemetryScheduler(), None)


def _roundtrip(msg: M.MAVLink_message) -> M.MAVLink_message:
    """What a receiver decodes from ``msg`` on the wire (float32 rounding included)."""
    parser = M.MAVLink(None, 0, 0)
    return parser.parse_buffer(bytes(msg.pack(M.MAVLink(None, 245, 191))))[0]


@PROPERTY
@given(st.binary(max_size=600))
def test_the_sitl_parser_takes_any_bytes(data: bytes) -> None:
    client = _Parser()
    msgs = client.parse(data)
    assert all(m.get_type() != "BAD_DATA" for m in msgs)


@PROPERTY
@given(st.integers(0, 255), st.integers(0, 0xFFFF), st.lists(any_float, min_size=11, max_size=11), st.integers(0, 2**32 - 1))
def test_the_sitl_handler_refuses_or_applies_any_setpoint_without_moving_a_grounded_vehicle(
    frame: int, mask: int, values: list[float], stamp: int
) -> None:
    h = grounded_handler()
    h.handle(_roundtrip(M.MAVLink_set_position_target_local_ned_message(stamp, 1, 1, frame, mask, *values)))
    assert not h.v.armed and h.v.landed


@PROPERTY
@given(st.sampled_from([M.MAV_CMD_DO_SET_MODE, M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAV_CMD_REQUEST_MESSAGE,
                        M.MAV_CMD_NAV_LAND, 0, 65535]), st.lists(any_float, min_size=7, max_size=7))
def test_the_sitl_handler_answers_any_command_parameters(cmd: int, params: list[float]) -> None:
    h = grounded_handler()
    result = h.handle(_roundtrip(M.MAVLink_command_long_message(1, 1, cmd, 0, *params)))
    acks = [o.message for o in result.replies if o.message.get_type() == "COMMAND_ACK"]
    assert len(acks) == 1 and not h.v.armed  # exactly one answer, and nothing armed


@PROPERTY
@given(st.sampled_from(["MIS_TAKEOFF_ALT", "COM_OF_LOSS_T", "MPC_XY_VEL_MAX", "NO_SUCH_PARAM"]), any_float, st.integers(0, 255))
def test_parameters_stay_finite_whatever_is_written(name: str, value: float, kind: int) -> None:
    h = grounded_handler()
    h.handle(_roundtrip(M.MAVLink_param_set_message(1, 1, name.encode(), value, kind)))
    assert all(math.isfinite(h.v.params.by_index(i).value) for i in range(len(h.v.params)))  # type: ignore[union-attr]


def _snapshot():  # type: ignore[no-untyped-def]
    hb = _roundtrip(M.MAVLink_heartbeat_message(M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_PX4, 0, 0, 3, 3))
    return initial_snapshot(hb, 0.0)


@PROPERTY
@given(st.sampled_from(["ATTITUDE", "LOCAL_POSITION_NED"]), st.integers(0, 2**32 - 1), st.lists(any_float, min_size=6, max_size=6))
def test_the_companion_folds_only_finite_telemetry(kind: str, stamp: int, values: list[float]) -> None:
    cls = M.MAVLink_attitude_message if kind == "ATTITUDE" else M.MAVLink_local_position_ned_message
    snap = _snapshot()
    try:
        new = apply_message(snap, _roundtrip(cls(stamp, *values)), 1.0, "SYSTEM_TIME")
    except InvalidTelemetry:
        return
    vec = [*new.position_ned_m, *new.velocity_ned_m_s, *new.attitude_rad, *new.rates_frd_rad_s]
    assert all(math.isfinite(v) for v in vec)


@PROPERTY
@given(st.lists(st.integers(-32768, 32767), min_size=4, max_size=4), st.integers(0, 0xFFFF))
def test_manual_control_is_refused_or_in_range(axes: list[int], buttons: int) -> None:
    value = parse_manual_control(_roundtrip(M.MAVLink_manual_control_message(1, *axes, buttons)), 0.0)
    if value is not None:
        scaled = [value.axis(k) for k in ("x", "y", "z", "r")]
        assert all(a is None or -1.0 <= a <= 1.0 for a in scaled)


@PROPERTY
@given(st.binary(max_size=80))
def test_a_signing_key_file_is_a_key_or_a_clear_error(data: bytes) -> None:
    try:
        assert len(parse_key(data)) == 32
    except ConfigError as exc:
        assert "signing key" in str(exc) or "all-zero" in str(exc)


def test_the_fuzz_generator_is_seeded_and_mixes_every_kind() -> None:
    a = list(packets(np.random.default_rng(3), 500))
    assert a == list(packets(np.random.default_rng(3), 500))
    assert {k for k, _ in a} == set(KINDS)


@pytest.mark.e2e
def test_a_running_sitl_survives_hostile_udp_and_does_nothing_it_was_not_asked() -> None:
    report, after = fuzz_sitl(2000, seed=7)
    assert report.packets == 2000 and report.crashes == 0 and report.hangs == 0, report.notes
    assert after["armed"] is False and after["landed"] is True
    assert abs(after["vehicle_ned"][2]) < 0.05 and max(abs(v) for v in after["vehicle_vel_ned"]) < 0.05


@pytest.mark.e2e
def test_the_companion_link_survives_hostile_udp(caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.ERROR)
    report, after = fuzz_link(2000, seed=7)
    assert report.packets == 2000 and report.crashes == 0 and report.hangs == 0, report.notes
    assert after["snapshot_finite"] and after["manual_control_in_range"]
    assert after["stats"]["bad_data"] > 0 and after["stats"]["thread_errors"] == 0
