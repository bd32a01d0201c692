"""Heights real PX4 SIH reported over one run, from its session.tlog, one row a second:

    python results/real-autopilots/heights.py RUN_DIR/session.tlog > results/real-autopilots/still/px4_heights.csv

time (s since boot), local z of LOCAL_POSITION_NED (m, down), the z of the newest HOME_POSITION,
the landed state (EXTENDED_SYS_STATE: 1 on ground, 2 in air) and the downward rangefinder (m).
"""

from __future__ import annotations

import sys

from pymavlink import mavutil


def main() -> None:
    log = mavutil.mavlink_connection(sys.argv[1])
    home = landed = rng = None
    last = -1.0
    print("t_s,z_m,home_z_m,landed_state,range_m")
    while (msg := log.recv_match(blocking=False)) is not None:
        kind = msg.get_type()
        if kind == "HOME_POSITION":
            home = round(msg.z, 3)
        elif kind == "EXTENDED_SYS_STATE":
            landed = msg.landed_state
        elif kind == "DISTANCE_SENSOR":
            rng = msg.current_distance / 100 if msg.current_distance <= msg.max_distance else None
        elif kind == "LOCAL_POSITION_NED" and msg.time_boot_ms / 1000 - last >= 1.0:
            last = msg.time_boot_ms / 1000
            print(f"{last:.1f},{msg.z:.3f},{home},{landed},{rng}")


if __name__ == "__main__":
    main()
