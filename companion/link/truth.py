"""The truth where an autopilot's SITL offers it: to check scores made from its estimate, and
for the rendered camera to see what a real camera would (docs/camera.md).

On a real vehicle the companion has only the autopilot's estimate; so on real autopilots the
touchdown is scored from the reported position (what a field test would have), and the true
distance is set beside it where the SITL knows the truth. With GPS_GLOBAL_ORIGIN (where the local
frame's origin is, and its altitude) the truth goes into the local frame, where the pad is given:

- PX4 SIH: HIL_STATE_QUATERNION, from SIH's ground truth: latitude, longitude, altitude (mm)
  and the attitude quaternion. Its ``time_usec`` would be the boot clock at the truth, but the
  prebuilt PX4 (2026-03-02) sends 0 there: then, as on ArduPilot, the newest vehicle time heard.
- ArduPilot SITL: SIM_STATE (common.xml; ArduPilot sends it from its simulator's state when asked
  by SET_MESSAGE_INTERVAL): ``lat_int``/``lon_int``, ``alt`` (metres AMSL) and the attitude
  quaternion ``q1..q4``. Its older SIMSTATE has no altitude; AHRS2/AHRS3 are estimates. Neither
  carries a time, so its pose is stamped with the newest vehicle time heard before it.

Nothing here is needed to fly; a vehicle that offers none of it just has no truth.
"""

from __future__ import annotations

import logging
import math
from typing import Any

from companion.errors import ColError
from companion.link.base import VehicleLink
from companion.msg.snapshot import VehicleSnapshot
from companion.msg.true_pose import TruePose

log = logging.getLogger(__name__)
TRUTH_MESSAGE = {"PX4": "HIL_STATE_QUATERNION", "ARDUPILOTMEGA": "SIM_STATE"}
TRUTH_RATE_HZ = 30.0  # the rendered camera's default rate ([companion.perception] render_rate_hz)
ORIGIN_RATE_HZ = 1.0  # the origin streamed too: an autopilot sets it only once its estimator has GPS
EARTH_RADIUS_M = 6_378_137.0  # WGS-84 equatorial: flat earth around the origin, exact to cm within km


def ask_for_truth(link: VehicleLink, autopilot: str, rate_hz: float = TRUTH_RATE_HZ) -> None:
    """Ask for the SITL's truth stream at ``rate_hz`` (the camera's rate: each frame then has a
    truth of its own) and the local origin, once now and then at ``ORIGIN_RATE_HZ`` (an origin
    set later still arrives); a refusal is logged."""
    name = TRUTH_MESSAGE.get(autopilot)
    if name is None:
        return
    try:
        result = link.request_rates({name: rate_hz, "GPS_GLOBAL_ORIGIN": ORIGIN_RATE_HZ}).get(name)
        origin = link.request_message("GPS_GLOBAL_ORIGIN", timeout_s=2.0)
    except (ColError, ValueError) as exc:  # nothing to fly for: said, and the run goes on
        log.info("no true position from the vehicle: %s", exc)
        return
    log.info("truth: %s at %.0f Hz %s, local origin %s", name, rate_hz, result, "known" if origin else "not sent")


def north_east_m(lat_lon_deg: tuple[float, float], origin_deg: tuple[float, float]) -> tuple[float, float]:
    """A point's north and east of the origin, in metres (flat earth)."""
    lat0 = math.radians(origin_deg[0])
    north = math.radians(lat_lon_deg[0] - origin_deg[0]) * EARTH_RADIUS_M
    east = math.radians(lat_lon_deg[1] - origin_deg[1]) * EARTH_RADIUS_M * math.cos(lat0)
    return north, east


def true_distance_m(snap: VehicleSnapshot, pad_ne_m: tuple[float, float]) -> float | None:
    """The true horizontal distance from the pad (at ``pad_ne_m`` of the local frame); None
    without a true position or the local origin."""
    if snap.truth_lat_lon_deg is None or snap.origin_lat_lon_deg is None:
        return None
    north, east = north_east_m(snap.truth_lat_lon_deg, snap.origin_lat_lon_deg)
    return math.hypot(north - pad_ne_m[0], east - pad_ne_m[1])


def euler_from_quaternion(w: float, x: float, y: float, z: float) -> tuple[float, float, float]:
    """(roll, pitch, yaw) in radians of a body-to-NED quaternion (MAVLink's order: w, x, y, z),
    as ATTITUDE gives them (aerospace Z-Y-X)."""
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return roll, pitch, yaw


def local_ned_m(lat_lon_deg: tuple[float, float], alt_m: float, snap: VehicleSnapshot) -> tuple[float, float, float] | None:
    """A global point in the snapshot's local frame (north, east, down of GPS_GLOBAL_ORIGIN);
    None until the origin, with its altitude, is known."""
    if snap.origin_lat_lon_deg is None or snap.origin_alt_m is None:
        return None
    north, east = north_east_m(lat_lon_deg, snap.origin_lat_lon_deg)
    return north, east, snap.origin_alt_m - alt_m


def _pose(snap: VehicleSnapshot, lat_e7: int, lon_e7: int, alt_m: float, q: tuple[float, float, float, float],
          time_boot_ms: int, source: str, now_s: float) -> TruePose | None:
    if lat_e7 == 0 and lon_e7 == 0:  # an empty message: no truth
        return None
    ned = local_ned_m((lat_e7 / 1e7, lon_e7 / 1e7), alt_m, snap)
    if ned is None:
        return None
    return TruePose(*ned, attitude_rad=euler_from_quaternion(*q), time_boot_ms=max(0, int(time_boot_ms)),
                    source=source, received_s=now_s)


def pose_from_hil_state(msg: Any, snap: VehicleSnapshot, now_s: float) -> TruePose | None:
    """PX4 SIH's HIL_STATE_QUATERNION as a true pose (alt in mm; ``time_usec`` on the boot clock,
    or 0: then the newest vehicle time heard)."""
    time_usec = int(msg.time_usec)
    time_boot_ms = time_usec // 1000 if time_usec > 0 else snap.time_boot_ms
    return _pose(snap, int(msg.lat), int(msg.lon), int(msg.alt) / 1000.0, tuple(msg.attitude_quaternion),
                 time_boot_ms, "HIL_STATE_QUATERNION", now_s)


def pose_from_sim_state(msg: Any, snap: VehicleSnapshot, now_s: float) -> TruePose | None:
    """ArduPilot SITL's SIM_STATE as a true pose: ``lat_int``/``lon_int`` (its float ``lat``/``lon``
    carry degE7, not the degrees the spec says), ``alt`` in metres; no time of its own."""
    return _pose(snap, int(msg.lat_int), int(msg.lon_int), float(msg.alt), (msg.q1, msg.q2, msg.q3, msg.q4),
                 snap.time_boot_ms, "SIM_STATE", now_s)


POSE_FROM = {"HIL_STATE_QUATERNION": pose_from_hil_state, "SIM_STATE": pose_from_sim_state}
