"""Touchdown on a pad driving at 1.0 and 1.5 m/s with the roof carrying the multirotor
([sitl.world] roof_carries = true) and without it: where it touches down, and how fast relative to
the surface it met (docs/sitl.md "The world").

    nice -n 10 python results/moving-pad/roof_carry_check.py --episodes 10 --out results/moving-pad/roof-carry-check.jsonl

Two pilots from the same held-out starts (seed 100000 on; the paper's undisturbed setting, the
pad driving north, the experiments' contact land detector: PX4's would not see a landing on a
roof at its LNDMC_XY_VEL_MAX of 1.5 m/s):

- ``expert``: the scripted expert through the companion, in-process and lockstep (a fence of
  200 m, which the driving pad does not leave in an episode);
- ``tracker``: a pilot of the SITL's own truth, offboard: the pad's position and velocity as the
  setpoint, descending at 0.7 m/s once within 0.3 m of it; it flies 25 s.

One line per episode: the pilot, the pad's speed, the key, the start's seed, the SITL's touchdown
judgement, the first contact after flight (world velocity and velocity relative to the surface it
met), where the multirotor is at the end relative to the pad and, for the tracker, the largest
tilt after contact.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

import companion.inprocess as inprocess
from colcommon.numeric_env import append_record
from companion.app import RunOptions, run_episodes
from companion.config import load_companion_config
from sitl.config import load_sitl_config
from sitl.dynamics import Contact
from sitl.modes import Mode
from sitl.offboard import FRAME_LOCAL_NED, TargetFields
from sitl.vehicle import SimVehicle

SPEEDS_M_S = (1.0, 1.5)
CONFIG = """
[sitl.world]
vehicle_velocity_ne_m_s = [{speed}, 0.0]
roof_carries = {carries}
vehicle_turn_rate_rad_s = {turn}
vehicle_speed_change = {change}

[sitl.autopilot]
land_detector = "contact"

[companion.safety]
fence_radius_m = 200.0  # the pad drives ~50 m in an episode: the session's fence is not the question here
"""

CONTACTS: dict[int, Contact] = {}


class WatchedSitl(inprocess.InProcessSitl):
    """The in-process SITL, keeping each episode's first contact after flight."""

    def advance(self) -> None:
        super().advance()
        contact = self.vehicle.dynamics.last_contact
        if contact is not None:
            CONTACTS.setdefault(self.vehicle.episode, contact)
        WATCHED["sitl"] = self


WATCHED: dict[str, WatchedSitl] = {}


def _rounded(values: Any) -> list[float]:
    return [round(float(v), 3) for v in values]


def contact_fields(contact: Contact | None) -> dict[str, Any]:
    if contact is None:
        return {"contact": None}
    rel = contact.relative_velocity_ned_m_s
    return {"contact": {
        "time_s": round(contact.time_s, 3), "position_ned_m": _rounded(contact.position_ned_m),
        "surface": "roof" if contact.surface_velocity_ned_m_s != (0.0, 0.0, 0.0) else "ground",
        "velocity_ned_m_s": _rounded(contact.velocity_ned_m_s), "relative_velocity_ned_m_s": _rounded(rel),
        "relative_horizontal_m_s": round(math.hypot(rel[0], rel[1]), 3), "relative_down_m_s": round(rel[2], 3)}}


def touchdown_fields(v: SimVehicle) -> dict[str, Any]:
    td = v.touchdown
    return {"touchdown": None if td is None else {
        "on_pad": td.on_pad, "success": td.success, "distance_to_pad_m": round(td.distance_to_pad_m, 3),
        "judged_speed_m_s": round(td.speed_m_s, 3), "time_s": round(td.time_s, 3)}}


def fly_expert(config: Path, speed_m_s: float, carries: bool, episodes: int, seed: int) -> list[dict[str, Any]]:
    """The scripted expert, in-process; each episode's first contact from the watched SITL."""
    lines: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="roof-carry-") as tmp:
        cfg = load_companion_config(config)
        CONTACTS.clear()

        def on_episode(record: Any) -> None:
            v = WATCHED["sitl"].vehicle
            lines.append({"pilot": "expert", "pad_speed_m_s": speed_m_s, "roof_carries": carries, "seed": record.seed,
                          "outcome": record.outcome, **touchdown_fields(v), **contact_fields(CONTACTS.get(v.episode)),
                          "end": end_fields(v)})

        run_episodes(cfg, RunOptions(pilot="expert", condition="demo", episodes=episodes, run_dir=Path(tmp) / "run",
                                     config_path=config, seed=seed, lockstep=True, learn=False, record=False),
                     on_episode=on_episode, vehicle=inprocess.inprocess_vehicle)
    return lines


TRACK_MASK = 0x5C4  # LOCAL_NED position x, y and velocity x, y, z (z, accelerations and yaw ignored)
TRACKER_S = 25.0


def fly_tracker(config: Path, speed_m_s: float, carries: bool, seed: int) -> dict[str, Any]:
    """The truth pilot on one start: the pad's position and velocity, descending once over it."""
    v = SimVehicle(load_sitl_config(config))
    v.reset_episode(seed)
    first: Contact | None = None
    tilt_rad = 0.0
    for i in range(round(TRACKER_S / v.dynamics.dt_s)):
        if i % 12 == 0:  # the companion's frame rate
            v.offboard_setpoint(track(v))
            if i == 0:
                v.request_mode(Mode.OFFBOARD)
        s = v.step()
        first = first or v.dynamics.last_contact
        if first is not None:
            tilt_rad = max(tilt_rad, abs(s.attitude_rad[0]), abs(s.attitude_rad[1]))
    return {"pilot": "tracker", "pad_speed_m_s": speed_m_s, "roof_carries": carries, "seed": seed,
            **touchdown_fields(v), **contact_fields(first), "max_tilt_after_contact_rad": round(tilt_rad, 3),
            "end": end_fields(v)}


def end_fields(v: SimVehicle) -> dict[str, Any]:
    """Where the multirotor is at the end, relative to the pad."""
    s = v.state
    pad = v.world.pad_ned(s.time_s)
    return {"off_pad_m": round(float(np.hypot(s.position_ned_m[0] - pad[0], s.position_ned_m[1] - pad[1])), 3),
            "height_above_pad_m": round(float(pad[2] - s.position_ned_m[2]), 3), "armed": v.armed,
            "velocity_ned_m_s": _rounded(s.velocity_ned_m_s)}


def track(v: SimVehicle) -> TargetFields:
    s = v.state
    pad = v.world.pad_ned(s.time_s)
    vn, ve = v.world.velocity_at(s.time_s)
    over = math.hypot(s.position_ned_m[0] - pad[0], s.position_ned_m[1] - pad[1]) < 0.3
    return TargetFields(FRAME_LOCAL_NED, TRACK_MASK, float(pad[0]), float(pad[1]), 0.0, float(vn), float(ve),
                        0.7 if over else 0.0, 0.0, 0.0)


def pilot_table(lead: bool, by_picture: bool) -> str:
    """The [companion.pilot] keys the expert flies with (empty: the experiment's expert)."""
    keys = ["lead_moving_pad = true"] * lead + ["set_down_by_picture = true"] * by_picture
    return "\n[companion.pilot]\n" + "\n".join(keys) + "\n" if keys else ""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument("--seed", type=int, default=100000)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--speeds", type=lambda t: tuple(float(v) for v in t.split(",")), default=SPEEDS_M_S,
                        help="pad speeds, m/s, comma-separated (default: 1.0,1.5)")
    parser.add_argument("--carries", choices=("both", "on"), default="both",
                        help="roof_carries off and on, or on only")
    parser.add_argument("--pilots", choices=("both", "expert"), default="both")
    parser.add_argument("--turn-rate", type=float, default=0.0,
                        help="[sitl.world] vehicle_turn_rate_rad_s: the pad's vehicle drives a curve")
    parser.add_argument("--speed-change", type=float, default=0.0,
                        help="[sitl.world] vehicle_speed_change: its speed swings by this share (period 20 s)")
    parser.add_argument("--lead-moving-pad", action="store_true",
                        help="[companion.pilot] lead_moving_pad = true: the expert follows the pad's motion")
    parser.add_argument("--set-down-by-picture", action="store_true",
                        help="[companion.pilot] set_down_by_picture = true: the expert steers by a partial pad too")
    args = parser.parse_args()
    inprocess.InProcessSitl = WatchedSitl  # type: ignore[misc]
    append_record(args.out.parent, command=sys.argv)  # the numeric environment and the code's commit
    with args.out.open("w") as out, tempfile.TemporaryDirectory(prefix="roof-carry-") as tmp:
        for speed in args.speeds:
            for carries in (False, True) if args.carries == "both" else (True,):
                config = Path(tmp) / f"{speed}-{carries}.toml"
                config.write_text(CONFIG.format(speed=speed, carries=str(carries).lower(), turn=args.turn_rate,
                                                change=args.speed_change)
                                  + pilot_table(args.lead_moving_pad, args.set_down_by_picture))
                lines = [] if args.pilots == "expert" else [
                    fly_tracker(config, speed, carries, args.seed + k) for k in range(args.episodes)]
                lines += [dict(line, lead_moving_pad=args.lead_moving_pad, turn_rate_rad_s=args.turn_rate,
                               set_down_by_picture=args.set_down_by_picture,
                               speed_change=args.speed_change)
                          for line in fly_expert(config, speed, carries, args.episodes, args.seed)]
                for line in lines:
                    out.write(json.dumps(line) + "\n")
                out.flush()


if __name__ == "__main__":
    main()
