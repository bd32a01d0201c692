"""Our SITL's precision landing on the task's pad, driving at several speeds, both personalities.

In process, no MAVLink: each episode starts as the experiment's do (hovering 8 m above the pad,
within +-3 m, armed), then LANDING_TARGET from the true pad position at the camera rate (10.5
Hz), only while the pad's centre is in the downward camera's field of view, and precision
landing asked for: PX4 AUTO.PRECLAND with LOCAL_NED targets, and with the angles form through its
landing target estimator (LTEST_MODE moving and stationary); ArduCopter LAND with PLND on
(BODY_FRD targets), with its defaults and with the moving-target option. An episode ends at touchdown
or after 60 s. Reports per case: touchdowns, successes (within 0.5 m of the pad's centre, on
the roof), touchdown distance, time to land. Last line of stdout: one JSON object.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import time
from dataclasses import dataclass

from machine_ref import machine_ref_rt

from sitl.config import CameraConfig, PersonalityConfig, SitlConfig, WorldConfig
from sitl.landing_target import (
    FRAME_BODY_FRD,
    FRAME_LOCAL_NED,
    TargetMeasurement,
    angles_of,
    ned_to_body,
)
from sitl.modes import Mode
from sitl.params import REAL32
from sitl.personality import CopterMode, CopterVehicle, make_vehicle
from sitl.vehicle import SimVehicle

EPISODE_S = 60.0
TARGET_EVERY_STEPS = 12  # 126 Hz / 12 = 10.5 Hz, the camera rate


@dataclass(frozen=True)
class Case:
    name: str
    personality: str
    params: tuple[tuple[str, float], ...] = ()
    angles: bool = False  # the angles form (position_valid 0) instead of a position


CASES = (
    Case("px4", "px4"),
    Case("px4 angles, LTEST_MODE 0 (moving)", "px4", angles=True),
    Case("px4 angles, LTEST_MODE 1 (stationary)", "px4", (("LTEST_MODE", 1.0),), angles=True),
    Case("ardupilot", "ardupilot"),
    Case("ardupilot moving-target", "ardupilot", (("PLND_OPTIONS", 1.0),)),
)


def in_view(body: tuple[float, float, float], cam: CameraConfig) -> bool:
    """The pad's centre is in the image (the camera looks down, image x to the right)."""
    if body[2] <= 0.1:
        return False
    ax, ay = angles_of(body)
    half_h = math.radians(cam.hfov_deg) / 2
    half_v = math.atan(math.tan(half_h) * cam.height_px / cam.width_px)
    return abs(ax) < half_h and abs(ay) < half_v


def target_for(v: SimVehicle, angles: bool) -> TargetMeasurement | None:
    """LANDING_TARGET as the companion's contract has it, from the truth."""
    s = v.state
    pad = v.world.pad_ned(s.time_s)
    rel = (pad[0] - s.position_ned_m[0], pad[1] - s.position_ned_m[1], pad[2] - s.position_ned_m[2])
    body = ned_to_body(rel, s.attitude_rad)
    if not in_view(body, v.cfg.camera):
        return None
    ax, ay = angles_of(body)
    distance = math.sqrt(sum(c * c for c in rel))
    if angles:
        return TargetMeasurement(s.time_s, ax, ay, distance, FRAME_BODY_FRD, False)
    if isinstance(v, CopterVehicle):
        return TargetMeasurement(s.time_s, ax, ay, distance, FRAME_BODY_FRD, True, *body)
    return TargetMeasurement(s.time_s, ax, ay, distance, FRAME_LOCAL_NED, True,
                             float(pad[0]), float(pad[1]), float(pad[2]) - v.height_offset_m)


def ask_for_precision_landing(v: SimVehicle) -> None:
    if isinstance(v, CopterVehicle):
        v.request_copter_mode(CopterMode.LAND)
    else:
        v.request_mode(Mode.AUTO_PRECLAND)


def episode(case: Case, pad_speed_m_s: float, seed: int) -> dict[str, object]:
    cfg = SitlConfig(personality=PersonalityConfig(autopilot=case.personality, prearm_settle_s=0.0),  # type: ignore[arg-type]
                     world=WorldConfig(vehicle_velocity_ne_m_s=(pad_speed_m_s, 0.0), seed=seed))
    v = make_vehicle(cfg)
    for name, value in case.params:
        v.set_param(name, value, REAL32)
    if isinstance(v, CopterVehicle):
        v.set_param("PLND_ENABLED", 1.0, REAL32)
        v.set_param("PLND_TYPE", 1.0, REAL32)
        v.reboot(1.0)  # PLND_TYPE takes effect at boot
    v.reset_episode(seed)
    start_s = v.time_s
    asked = False
    while v.touchdown is None and v.time_s - start_s < EPISODE_S:
        if v.dynamics.steps % TARGET_EVERY_STEPS == 0 and (m := target_for(v, case.angles)) is not None:
            v.landing_target(m)
        if not asked and v.time_s - start_s > 0.5:
            asked = True
            ask_for_precision_landing(v)
        v.step()
    td = v.touchdown
    if td is None:
        return {"outcome": "timeout", "state": v.precision_landing_state()}
    return {"outcome": "touchdown", "success": td.success, "distance_m": round(td.distance_to_pad_m, 3),
            "time_s": round(td.time_s - start_s, 1)}


def summarise(runs: list[dict[str, object]]) -> dict[str, object]:
    landed = [r for r in runs if r["outcome"] == "touchdown"]
    dist = sorted(float(r["distance_m"]) for r in landed)  # type: ignore[arg-type]
    return {
        "episodes": len(runs),
        "touchdowns": len(landed),
        "successes": sum(1 for r in landed if r["success"]),
        "distance_m_median": round(statistics.median(dist), 3) if dist else None,
        "distance_m_max": round(dist[-1], 3) if dist else None,
        "time_s_median": round(statistics.median(float(r["time_s"]) for r in landed), 1) if landed else None,  # type: ignore[arg-type]
        "timeouts_in": sorted({str(r["state"]) for r in runs if r["outcome"] == "timeout"}),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="2 seeds, 2 pad speeds")
    parser.add_argument("--seeds", type=int, default=10)
    args = parser.parse_args()
    machine_ref = machine_ref_rt()
    speeds = (0.0, 0.5) if args.quick else (0.0, 0.1, 0.25, 0.5, 1.0)
    seeds = range(2 if args.quick else args.seeds)
    start = time.perf_counter()
    results: dict[str, dict[str, object]] = {}
    for case in CASES:
        for speed in speeds:
            runs = [episode(case, speed, seed) for seed in seeds]
            results[f"{case.name} @ {speed:g} m/s"] = summarise(runs)
            print(f"{case.name:38s} pad {speed:4g} m/s: {results[f'{case.name} @ {speed:g} m/s']}")
    print(json.dumps({"cases": results, "episode_s_max": EPISODE_S, "seeds": len(seeds),
                      "wall_s": round(time.perf_counter() - start, 1), "machine_ref_rt": round(machine_ref, 1)}))


if __name__ == "__main__":
    main()
