"""The true position where an autopilot's SITL offers one, to check scores made from its estimate.

On a real vehicle the companion has only the autopilot's estimate; so on real autopilots the
touchdown is scored from the reported position (what a field test would have). Their SITLs also
know the truth: PX4 SIH streams HIL_STATE_QUATERNION from its ground truth, ArduPilot's SITL
SIMSTATE. With GPS_GLOBAL_ORIGIN (where the local frame's origin is) the pad, given in the local
frame, goes on the true map, and the true touchdown distance can be set beside the estimated
one. Nothing here is needed to fly; a vehicle that offers none of it just has no truth.
"""

from __future__ import annotations

import logging
import math

from companion.errors import ColError
from companion.link.base import VehicleLink
from companion.msg.snapshot import VehicleSnapshot

log = logging.getLogger(__name__)
TRUTH_MESSAGE = {"PX4": "HIL_STATE_QUATERNION", "ARDUPILOTMEGA": "SIMSTATE"}
TRUTH_RATE_HZ = 5.0
EARTH_RADIUS_M = 6_378_137.0  # WGS-84 equatorial: flat earth around the origin, exact to cm within km


def ask_for_truth(link: VehicleLink, autopilot: str) -> None:
    """Ask for the SITL's true position stream and the local origin; a refusal is logged."""
    name = TRUTH_MESSAGE.get(autopilot)
    if name is None:
        return
    try:
        result = link.request_rates({name: TRUTH_RATE_HZ}).get(name)
        origin = link.request_message("GPS_GLOBAL_ORIGIN", timeout_s=2.0)
    except (ColError, ValueError) as exc:  # nothing to fly for: said, and the run goes on
        log.info("no true position from the vehicle: %s", exc)
        return
    log.info("true position: %s %s, local origin %s", name, result, "known" if origin else "not sent")


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
