"""The SITL's true pose for the rendered camera: PX4 SIH's HIL_STATE_QUATERNION and ArduPilot's
SIM_STATE folded into the local frame of GPS_GLOBAL_ORIGIN, with the vehicle's time."""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.link.telemetry import InvalidTelemetry, apply_message
from companion.link.truth import TRUTH_MESSAGE, ask_for_truth, euler_from_quaternion
from companion.msg.true_pose import TruePose
from tests.control.test_touchdown import snap

M_PER_DEG_LAT = 111_319.49  # one degree of latitude at the WGS-84 equatorial radius
PX4_ORIGIN = (47.397742, 8.545594, 488.123)
AP_ORIGIN = (-35.3632621, 149.1652374, 584.090)  # real ArduCopter SITL's GPS_GLOBAL_ORIGIN


def quaternion(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """w, x, y, z of yaw about z, then pitch about y, then roll about x (built independently)."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy)


def origin_message(lat: float, lon: float, alt_m: float) -> Any:
    return mavlink.MAVLink_gps_global_origin_message(round(lat * 1e7), round(lon * 1e7), round(alt_m * 1000), 0)


def offset(origin: tuple[float, float, float], north_m: float, east_m: float) -> tuple[int, int]:
    lat = origin[0] + north_m / M_PER_DEG_LAT
    lon = origin[1] + east_m / (M_PER_DEG_LAT * math.cos(math.radians(origin[0])))
    return round(lat * 1e7), round(lon * 1e7)


def fold(s: Any, *messages: Any, now_s: float = 5.0) -> Any:
    for msg in messages:
        s = apply_message(s, msg, now_s, "SYSTEM_TIME")
    return s


def hil_state(north_m: float, east_m: float, height_m: float, q: tuple[float, ...], time_usec: int) -> Any:
    lat, lon = offset(PX4_ORIGIN, north_m, east_m)
    alt_mm = round((PX4_ORIGIN[2] + height_m) * 1000)
    return mavlink.MAVLink_hil_state_quaternion_message(time_usec, list(q), 0, 0, 0, lat, lon, alt_mm,
                                                        0, 0, 0, 0, 0, 0, 0, 0)


def test_euler_from_quaternion_inverts_the_aerospace_rotation() -> None:
    for rpy in [(0.0, 0.0, 0.0), (0.1, -0.2, 1.0), (-0.4, 0.3, -2.9), (0.0, 0.0, math.pi - 0.01)]:
        assert euler_from_quaternion(*quaternion(*rpy)) == pytest.approx(rpy, abs=1e-9)


def test_px4_hil_state_quaternion_is_a_true_pose_in_the_local_frame_at_its_own_time() -> None:
    hil = hil_state(3.0, -4.0, 5.0, quaternion(0.1, -0.2, 1.0), time_usec=12_345_678)
    s = fold(replace(snap(), time_boot_ms=99_999), hil)
    assert s.true_pose is None  # no origin yet: no local frame to put the truth in
    assert s.truth_lat_lon_deg is not None  # the true distance's lat/lon is kept as before
    s = fold(s, origin_message(*PX4_ORIGIN), hil)
    pose = s.true_pose
    assert isinstance(pose, TruePose) and pose.source == "HIL_STATE_QUATERNION"
    assert pose.position_ned_m == pytest.approx((3.0, -4.0, -5.0), abs=0.01)
    assert pose.attitude_rad == pytest.approx((0.1, -0.2, 1.0), abs=1e-6)
    assert pose.time_boot_ms == 12_345  # time_usec on the boot clock, not the snapshot's newest stamp
    assert pose.received_s == 5.0
    assert s.origin_alt_m == pytest.approx(PX4_ORIGIN[2])
    # The prebuilt PX4 sends time_usec = 0 (and q = -1, 0, 0, 0 for no rotation): the newest vehicle time.
    unstamped = fold(s, hil_state(0.0, 0.0, 0.0, (-1.0, 0.0, 0.0, 0.0), time_usec=0)).true_pose
    assert unstamped is not None and unstamped.time_boot_ms == 99_999
    assert unstamped.attitude_rad == pytest.approx((0.0, 0.0, 0.0), abs=1e-12)


def test_ardupilot_sim_state_is_a_true_pose_with_its_altitude() -> None:
    # A real ArduCopter SITL's SIM_STATE on the ground, moved 2 m north, 1 m east and 2.5 m up.
    q = (0.9981347918510437, 0.0, 0.0, -0.06104858219623566)
    lat, lon = offset(AP_ORIGIN, 2.0, 1.0)
    sim = mavlink.MAVLink_sim_state_message(*q, 0.0, 0.0, -0.12217313796281815, 0, 0, -9.8, 0, 0, 0,
                                            lat, lon, AP_ORIGIN[2] + 2.5, 0, 0, 0, 0, 0, lat, lon)
    s = fold(replace(snap(), time_boot_ms=33_014), origin_message(*AP_ORIGIN), sim)
    pose = s.true_pose
    assert pose is not None and pose.source == "SIM_STATE"
    assert pose.position_ned_m == pytest.approx((2.0, 1.0, -2.5), abs=0.01)
    assert pose.attitude_rad == pytest.approx((0.0, 0.0, -0.12217313796281815), abs=1e-6)  # its own Euler fields
    assert pose.time_boot_ms == 33_014  # no time of its own: the newest vehicle time heard
    assert s.truth_lat_lon_deg == pytest.approx((lat / 1e7, lon / 1e7))


def test_the_older_simstate_has_no_altitude_and_gives_no_pose() -> None:
    sim = mavlink.MAVLink_simstate_message(0, 0, 0, 0, 0, 0, 0, 0, 0, -353632621, 1491652374)
    s = fold(snap(), origin_message(*AP_ORIGIN), sim)
    assert s.true_pose is None and s.truth_lat_lon_deg == (-35.3632621, 149.1652374)


def test_non_finite_truth_is_rejected_and_an_empty_one_is_no_truth() -> None:
    s = fold(snap(), origin_message(*PX4_ORIGIN))
    bad = hil_state(0.0, 0.0, 1.0, (float("nan"), 0.0, 0.0, 0.0), time_usec=1000)
    with pytest.raises(InvalidTelemetry):
        fold(s, bad)
    empty = mavlink.MAVLink_hil_state_quaternion_message(0, [1, 0, 0, 0], 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0)
    assert fold(s, empty).true_pose is None


class RatesLink:
    def __init__(self) -> None:
        self.asked: list[dict[str, float]] = []

    def request_rates(self, rates_hz: dict[str, float]) -> dict[str, str]:
        self.asked.append(dict(rates_hz))
        return dict.fromkeys(rates_hz, "ACCEPTED")

    def request_message(self, name: str, timeout_s: float = 2.0) -> None:
        return None


def test_truth_is_asked_for_at_the_cameras_rate_and_sim_state_on_ardupilot() -> None:
    assert TRUTH_MESSAGE == {"PX4": "HIL_STATE_QUATERNION", "ARDUPILOTMEGA": "SIM_STATE"}
    link = RatesLink()
    ask_for_truth(link, "ARDUPILOTMEGA", rate_hz=25.0)  # type: ignore[arg-type]
    ask_for_truth(link, "PX4")  # type: ignore[arg-type]
    ask_for_truth(link, "UNKNOWN(3)")  # type: ignore[arg-type]
    assert link.asked == [{"SIM_STATE": 25.0, "GPS_GLOBAL_ORIGIN": 1.0},
                          {"HIL_STATE_QUATERNION": 30.0, "GPS_GLOBAL_ORIGIN": 1.0}]


def test_a_true_pose_checks_itself() -> None:
    with pytest.raises(ValueError):
        TruePose(0.0, float("inf"), 0.0, (0.0, 0.0, 0.0), 0, "SIM_STATE", 0.0)
    with pytest.raises(ValueError):
        TruePose(0.0, 0.0, 0.0, (0.0, 0.0, 0.0), -1, "SIM_STATE", 0.0)
    with pytest.raises(ValueError):
        TruePose(0.0, 0.0, 0.0, (0.0, 0.0), 0, "SIM_STATE", 0.0)  # type: ignore[arg-type]
