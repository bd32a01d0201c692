"""Where an autopilot's SITL truth puts the vehicle standing on the ground, against the local
origin's altitude (the level companion/control/truth_contact.py measures instead of assuming).

    python results/moving-pad/truth-ground/check.py ardupilot|px4   # prints one JSON line

Starts the autopilot fresh (speed-up 4), asks for its truth (ArduPilot SIM_STATE, PX4
HIL_STATE_QUATERNION) at 10 Hz and GPS_GLOBAL_ORIGIN, and listens for 60 s of wall time while the
vehicle stands disarmed.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

from pymavlink import mavutil

from companion.testing.autopilots import find_autopilots, start_ardupilot, start_px4

TRUTH = {"ardupilot": ("SIM_STATE", 108), "px4": ("HIL_STATE_QUATERNION", 115)}


def main(kind: str) -> None:
    root, why = find_autopilots()
    if root is None:
        raise SystemExit(why)
    name, msg_id = TRUTH[kind]
    start = start_ardupilot if kind == "ardupilot" else start_px4
    with start(root, Path("runs/truth-ground").resolve() / kind, speedup=4.0) as ap:
        link = mavutil.mavlink_connection(ap.connection, source_system=255)
        link.wait_heartbeat(timeout=60)
        for mid, hz in ((msg_id, 10.0), (49, 1.0)):  # the truth, GPS_GLOBAL_ORIGIN
            link.mav.command_long_send(link.target_system, 1, 511, 0, mid, 1e6 / hz, 0, 0, 0, 0, 0)
        origin, heights, t0 = None, [], time.time()
        while time.time() - t0 < 60:
            msg = link.recv_match(type=[name, "GPS_GLOBAL_ORIGIN"], blocking=True, timeout=1)
            if msg is None:
                continue
            if msg.get_type() == "GPS_GLOBAL_ORIGIN":
                origin = msg.altitude / 1000.0
            elif origin is not None:
                alt = msg.alt if name == "SIM_STATE" else msg.alt / 1000.0
                heights.append(alt - origin)
    print(json.dumps({"autopilot": kind, "truth": name, "origin_alt_m": origin, "samples": len(heights),
                      "true_height_above_origin_m": {"min": min(heights), "max": max(heights)} if heights else None}))


if __name__ == "__main__":
    main(sys.argv[1])
