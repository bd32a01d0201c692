"""How much faster than real time the simulated vehicle runs in process.

Flies JSBSim's F450 under our flight controller (Dynamics.step + FlightController.update at
the FDM rate) through hovers, body-velocity steps, turns and descents over the world's ground
vehicle, with no MAVLink. The machine may be shared: numbers vary with its load, so the best
of a few repeats is reported. Last line of stdout: one JSON object.
"""

from __future__ import annotations

import argparse
import json
import math
import time

from machine_ref import machine_ref_rt

from sitl.config import SitlConfig
from sitl.control import FlightController, Setpoint
from sitl.dynamics import Dynamics
from sitl.world import World

NAN = math.nan


def flight_plan(seconds_each: float) -> list[tuple[Setpoint, float]]:
    """A mix of hover and velocity steps, in a loop that returns near its start."""
    hold = Setpoint(position_ned_m=(0.0, 0.0, -8.0), yaw_rad=0.0)
    return [
        (hold, seconds_each),
        (Setpoint(velocity_ned_m_s=(1.0, 0.0, 0.0)), seconds_each),
        (Setpoint(velocity_ned_m_s=(0.0, -2.0, 0.0), yaw_rate_rad_s=0.5), seconds_each),
        (Setpoint(velocity_ned_m_s=(-1.0, 1.0, 0.5)), seconds_each),
        (hold, seconds_each),
        (Setpoint(velocity_ned_m_s=(0.0, 0.0, -1.0), yaw_rate_rad_s=-0.5), seconds_each),
    ]


def fly(sim_s: float, cfg: SitlConfig) -> tuple[float, int]:
    """Fly ``sim_s`` seconds of the plan; return the wall time and the number of steps."""
    world = World(cfg.world)
    dyn = Dynamics(
        cfg.clock.fdm_rate_hz,
        surface_height_m=world.surface_height_m,
        max_surface_height_m=world.roof_height_m,
    )
    fc = FlightController(cfg.autopilot, dyn.dt_s)
    state = dyn.reset((0.0, 0.0, -8.0), time_s=0.0)
    plan = flight_plan(seconds_each=5.0)
    schedule: list[Setpoint] = []
    while len(schedule) * dyn.dt_s < sim_s:
        for sp, seconds in plan:
            schedule.extend([sp] * round(seconds / dyn.dt_s))
    schedule = schedule[: math.ceil(sim_s / dyn.dt_s)]
    step, update = dyn.step, fc.update
    start = time.perf_counter()
    for sp in schedule:
        state = step(update(state, sp, True))
    return time.perf_counter() - start, len(schedule)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="a short run (10 s, one repeat)")
    parser.add_argument("--sim-s", type=float, default=60.0, help="simulated seconds per run")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    machine_ref = machine_ref_rt()  # at the start, before the bench's own work
    sim_s, repeats = (10.0, 1) if args.quick else (args.sim_s, args.repeats)
    cfg = SitlConfig()
    runs = [fly(sim_s, cfg) for _ in range(max(1, repeats))]
    wall_s, steps = min(runs)
    flown_s = steps / cfg.clock.fdm_rate_hz
    print(f"{steps} steps at {cfg.clock.fdm_rate_hz:g} Hz: {wall_s / steps * 1e6:.2f} us per step")
    result = {
        "fdm_realtime_factor": round(flown_s / wall_s, 1),
        "sim_s": round(flown_s, 3),
        "wall_s": round(wall_s, 4),
        "us_per_step": round(wall_s / steps * 1e6, 2),
        "fdm_rate_hz": cfg.clock.fdm_rate_hz,
        "repeats": len(runs),
        "note": "best of repeats; shared machine, load varies",
        "machine_ref_rt": round(machine_ref, 1),
    }
    print(json.dumps(result))


if __name__ == "__main__":
    main()
