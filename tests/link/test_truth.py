"""The SITL's true position beside the estimate: folded from PX4 SIH's HIL_STATE_QUATERNION and
ArduPilot's SIMSTATE, and the pad put on the true map through GPS_GLOBAL_ORIGIN."""

from __future__ import annotations

from dataclasses import replace

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.link.telemetry import HANDLERS
from companion.link.truth import north_east_m, true_distance_m
from tests.control.test_touchdown import snap

ORIGIN = (47.397742, 8.545594)


def test_a_metre_north_and_east_of_the_origin() -> None:
    lat = ORIGIN[0] + 1.0 / 111_319.49  # one metre of latitude at the WGS-84 radius
    north, east = north_east_m((lat, ORIGIN[1]), ORIGIN)
    assert north == pytest.approx(1.0, abs=1e-3) and east == pytest.approx(0.0, abs=1e-9)
    _, east = north_east_m((ORIGIN[0], ORIGIN[1] + 1.0 / (111_319.49 * 0.6766)), ORIGIN)
    assert east == pytest.approx(1.0, abs=5e-3)  # cos(47.4 deg) = 0.6766


def test_the_true_distance_needs_both_the_truth_and_the_origin() -> None:
    s = snap()
    assert true_distance_m(s, (0.0, 0.0)) is None
    three_north = (ORIGIN[0] + 3.0 / 111_319.49, ORIGIN[1])
    s = replace(s, truth_lat_lon_deg=three_north, origin_lat_lon_deg=ORIGIN)
    assert true_distance_m(s, (0.0, 0.0)) == pytest.approx(3.0, abs=1e-2)
    assert true_distance_m(s, (3.0, 4.0)) == pytest.approx(4.0, abs=1e-2)


def test_truth_and_origin_messages_are_folded_and_an_empty_one_is_no_truth() -> None:
    hil = mavlink.MAVLink_hil_state_quaternion_message(0, [1, 0, 0, 0], 0, 0, 0, 473977486, 85455961, 489267,
                                                       0, 0, 0, 0, 0, 0, 0, 0)
    assert HANDLERS["HIL_STATE_QUATERNION"](hil, 0.0) == {"truth_lat_lon_deg": (47.3977486, 8.5455961)}
    sim = mavlink.MAVLink_simstate_message(0, 0, 0, 0, 0, 0, 0, 0, 0, -353632621, 1491652374)
    assert HANDLERS["SIMSTATE"](sim, 0.0) == {"truth_lat_lon_deg": (-35.3632621, 149.1652374)}
    origin = mavlink.MAVLink_gps_global_origin_message(0, 0, 0, 0)
    assert HANDLERS["GPS_GLOBAL_ORIGIN"](origin, 0.0) == {"origin_lat_lon_deg": None}
