"""How much faster than real time the SITL runs.

- ``fdm_realtime_factor``: the simulated vehicle (JSBSim dynamics, autopilot cascade, modes,
  failsafes) stepped in this process, no I/O.
- ``lockstep_realtime_factor``: the SITL in another process in lockstep, a raw pymavlink
  client here closing the loop at 10.5 Hz over UDP: each SYSTEM_TIME frame marker is answered
  with a body-velocity setpoint that echoes it.

Each runs at least 60 s of simulated flight. Last line: one JSON object.
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import socket
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from machine_ref import machine_ref_rt  # noqa: E402
from pymavlink.dialects.v20 import common as mavlink  # noqa: E402

from companion.simulator import SimulatorClient, start_sitl  # noqa: E402
from sitl.config import SitlConfig  # noqa: E402
from sitl.control import Setpoint  # noqa: E402
from sitl.vehicle import SimVehicle  # noqa: E402

BODY_NED = 8
VEL_YAWRATE_MASK = 0x5C7


def in_process_factor(sim_s: float) -> float:
    """Steps the vehicle with an offboard-like pattern of velocity setpoints, no sockets."""
    cfg = SitlConfig()
    v = SimVehicle(cfg)
    v.reset_episode(seed=1)
    steps = int(sim_s * cfg.clock.fdm_rate_hz)
    start = time.perf_counter()
    for i in range(steps):
        if i % 12 == 0:
            t = v.time_s
            v.status.setpoint = Setpoint(velocity_ned_m_s=(math.sin(0.5 * t), math.cos(0.5 * t), 0.0), yaw_rate_rad_s=0.1)
        v.step()
    wall = time.perf_counter() - start
    return steps / cfg.clock.fdm_rate_hz / wall


def _command(mav: mavlink.MAVLink, cmd: int, *params: float) -> bytes:
    p = list(params) + [0.0] * (7 - len(params))
    return mavlink.MAVLink_command_long_message(1, 1, cmd, 0, *p).pack(mav)


def lockstep_factor(sim_s: float) -> tuple[float, dict]:
    """Closes the loop over UDP against a lockstep SITL in another process."""
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(5.0)
    port = rx.getsockname()[1]
    sitl = start_sitl(port, clock="lockstep", camera=False)
    mav = mavlink.MAVLink(None, 255, 190)
    parser = mavlink.MAVLink(None, 0, 0)
    try:
        data, peer = rx.recvfrom(65535)  # first telemetry tells us where the SITL is
        ctl = SimulatorClient("127.0.0.1", sitl.control_port)
        ctl.reset(seed=3)
        frames, t0_ms, wall0 = 0, None, None
        offboard_requested = False
        while True:
            data, peer = rx.recvfrom(65535)
            for msg in parser.parse_buffer(data) or []:
                if msg.get_type() != "SYSTEM_TIME":
                    continue
                t_ms = msg.time_boot_ms
                if t0_ms is None and frames == 2:  # the SITL is attached (strict lockstep) from here
                    t0_ms, wall0 = t_ms, time.perf_counter()
                ts = t_ms / 1000.0
                sp = mavlink.MAVLink_set_position_target_local_ned_message(
                    t_ms, 1, 1, BODY_NED, VEL_YAWRATE_MASK, 0, 0, 0,
                    math.sin(0.5 * ts), math.cos(0.5 * ts), 0.0, 0, 0, 0, 0, 0.1,
                )
                rx.sendto(sp.pack(mav), peer)
                if not offboard_requested and frames > 3:
                    rx.sendto(_command(mav, mavlink.MAV_CMD_DO_SET_MODE, 1, 6, 0), peer)
                    offboard_requested = True
                frames += 1
            if t0_ms is not None and frames and (t_ms - t0_ms) / 1000.0 >= sim_s:
                break
        wall = time.perf_counter() - wall0
        truth = ctl.truth()
        ctl.close()
        return (t_ms - t0_ms) / 1000.0 / wall, {"frames": frames, "mode": truth["mode"], "landed": truth["landed"]}
    finally:
        sitl.stop()
        rx.close()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sim-seconds", type=float, default=60.0, help="simulated flight per measurement (>= 60 for the goal)")
    ap.add_argument("--quick", action="store_true", help="10 s each, for a smoke run")
    args = ap.parse_args()
    machine_ref = machine_ref_rt()  # at the start, before the bench's own work
    sim_s = 10.0 if args.quick else args.sim_seconds
    fdm = in_process_factor(sim_s)
    lock, extra = lockstep_factor(sim_s)
    result = {
        "fdm_realtime_factor": round(fdm, 1),
        "lockstep_realtime_factor": round(lock, 1),
        "sim_seconds": sim_s,
        "lockstep_frames": extra["frames"],
        "final_mode": extra["mode"],
        "goal_lockstep_realtime_factor": 100,
        "machine": f"{platform.machine()} {platform.processor() or ''} cpus={__import__('os').cpu_count()}".strip(),
        "machine_ref_rt": round(machine_ref, 1),
    }
    print(json.dumps(result))


if __name__ == "__main__":
    main()
