"""The done-when of the real-autopilot work: `col fly --pilot expert --episodes 5` on a freshly
started real PX4 SIH and a freshly started real ArduCopter SITL, repeated on fresh instances.

    python results/real-autopilots/run.py --repeats 5 --out results/real-autopilots/still
    python results/real-autopilots/run.py --repeats 1 --episodes 20 --camera render --out results/real-autopilots/render

Each repeat starts both autopilots at once (their own ports, fresh folders), flies them side by
side, and stops them; the camera is a still video of the pad from 1 m above it (the autopilots
render none). Writes runs.jsonl (one line per episode, with the repeat and autopilot) and
summary.json (touchdowns and fence stops per run), both from the runs' own episodes.jsonl.
"""

from __future__ import annotations

import argparse
import json
import re
import statistics
import subprocess
import sys
import tempfile
import threading
from pathlib import Path

from companion.testing.autopilots import find_autopilots, start_ardupilot, start_px4
from companion.testing.still_pad import write_still_pad_video

CONFIG = """
[companion.session]
start_height_above_pad_m = 3.0
start_xy_range_m = 1.0
"""
RENDER = """
[companion.session]
start_height_above_pad_m = 3.0
start_xy_range_m = 1.0
pad_ned_m = [0.0, 0.0, 0.0]  # the pad on the autopilot's own ground

[companion.perception]
camera = "render"  # our renderer driven by the vehicle's telemetry

[sitl.world]
vehicle_height_m = 0.0
"""


def fly(kind: str, root: Path, work: Path, camera: Path | None, config: Path, episodes: int,
        speedup: float = 1.0, seed: int | None = None) -> list[dict]:
    ap = (start_px4 if kind == "px4" else start_ardupilot)(root, work / kind, speedup=speedup)
    run_dir = work / f"run-{kind}"
    col = str(Path(sys.executable).with_name("col"))
    try:
        cmd = [col, "fly", "--pilot", "expert", "--episodes", str(episodes), "--connect", ap.connection,
               "--config", str(config), "--run-dir", str(run_dir)] + ([] if seed is None else ["--seed", str(seed)])
        done = subprocess.run(cmd + (["--camera", str(camera)] if camera is not None else []),
                              capture_output=True, text=True, timeout=1800, stdin=subprocess.DEVNULL)
    finally:
        ap.stop()
    (work / f"{kind}.out").write_text(done.stdout + done.stderr)
    path = run_dir / "episodes.jsonl"
    return [json.loads(line) for line in path.read_text().splitlines()] if path.exists() else []


ESTIMATE_OFF = re.compile(r"estimate off the truth at (\d+) frames: horizontal median ([\d.]+) m, p95 ([\d.]+) m")


def estimate_off(records: list[dict]) -> dict[str, object] | None:
    """The rendered camera's per-episode notes on how far the estimate was from the truth at the
    frames drawn from truth: the median over episodes of each episode's median and p95."""
    found = [m for r in records for note in r.get("notes", []) if (m := ESTIMATE_OFF.search(note))]
    if not found:
        return None
    return {"episodes": len(found), "frames": sum(int(m[1]) for m in found),
            "horizontal_median_m": round(statistics.median(float(m[2]) for m in found), 3),
            "horizontal_p95_m": round(statistics.median(float(m[3]) for m in found), 3)}


def one(results: dict[str, list[dict]], kind: str, *args: object) -> None:
    results[kind] = fly(kind, *args)  # type: ignore[arg-type]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--episodes", type=int, default=5)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--camera", choices=("still", "render"), default="still",
                        help="still: a video of the pad from 1 m; render: the pad world rendered from telemetry")
    parser.add_argument("--autopilots", default="px4,ardupilot")
    parser.add_argument("--set-down-by-picture", action="store_true",
                        help="[companion.pilot] set_down_by_picture: once committed, the expert still steers by a "
                             "partial pad whose centre is in the picture (RENDER.md, 2026-12-05)")
    parser.add_argument("--judge-drift-by-picture", action="store_true",
                        help="[companion.pilot] judge_drift_by_picture: the expert judges the drift its ground-speed "
                             "reading does not show from the pad sliding across the picture (RENDER.md, 2026-12-06)")
    parser.add_argument("--disturbance", type=float, default=None, metavar="LEVEL",
                        help="[sitl.disturbance] level, set in each autopilot's own SITL per episode "
                             "([companion.session] autopilot_sim_disturbance: ArduCopter's wind and turbulence, the "
                             "rendered pad's drive; docs/link.md)")
    parser.add_argument("--sih-mass-scale", type=float, default=1.0,
                        help="PX4 SIH's SIH_MASS times this ([companion.session] sih_mass_scale)")
    parser.add_argument("--speedup", type=float, default=1.0,
                        help="the autopilots this many times real time (PX4_SIM_SPEED_FACTOR, --speedup), flown "
                             "by the vehicle's clock")
    parser.add_argument("--seed", type=int, default=None,
                        help="episode i starts from seed + i (col fly --seed; default: the session's seed)")
    args = parser.parse_args()
    root, why = find_autopilots()
    if root is None:
        raise SystemExit(why)
    args.out.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix="real-autopilots-"))
    config = work / "config.toml"
    text = CONFIG if args.camera == "still" else RENDER
    if args.speedup != 1.0:
        text = text.replace("[companion.session]\n", '[companion.session]\nclock = "vehicle"\n', 1)
    if args.disturbance is not None:
        text = text.replace("[companion.session]\n", "[companion.session]\nautopilot_sim_disturbance = true\n", 1)
        text += f"\n[sitl.disturbance]\nlevel = {args.disturbance:g}\n"
    if args.sih_mass_scale != 1.0:
        text = text.replace("[companion.session]\n", f"[companion.session]\nsih_mass_scale = {args.sih_mass_scale:g}\n", 1)
    pilot = [line for flag, line in ((args.set_down_by_picture, "set_down_by_picture = true"),
                                     (args.judge_drift_by_picture, "judge_drift_by_picture = true")) if flag]
    if pilot:
        text += "\n[companion.pilot]\n" + "\n".join(pilot) + "\n"
    config.write_text(text)
    camera = write_still_pad_video(work / "pad.mp4", height_above_pad_m=1.0, seconds=1200.0) if args.camera == "still" else None
    kinds = tuple(k for k in args.autopilots.split(",") if k)
    lines, summary = [], []
    for repeat in range(args.repeats):
        results: dict[str, list[dict]] = {}
        rep_dir = work / f"repeat-{repeat}"

        threads = [threading.Thread(target=one, args=(results, k, root, rep_dir, camera, config, args.episodes,
                                                      args.speedup, args.seed)) for k in kinds]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        for kind, records in sorted(results.items()):
            outcomes = [r["outcome"] for r in records]
            judged = [r["success"] for r in records if r["success"] is not None]
            est = [r["touchdown_distance_m"] for r in records if r.get("touchdown_distance_m") is not None]
            true = [r["true_touchdown_distance_m"] for r in records if r.get("true_touchdown_distance_m") is not None]
            summary.append({"repeat": repeat, "autopilot": kind, "episodes": len(records),
                            "touchdowns": outcomes.count("touchdown"), "fence": outcomes.count("fence"),
                            "on_pad": sum(judged) if judged else None,
                            "distance_m_median": round(statistics.median(est), 3) if est else None,
                            "true_distance_m_median": round(statistics.median(true), 3) if true else None,
                            "estimate_off_truth": estimate_off(records),
                            "outcomes": outcomes})
            lines += [dict(r, repeat=repeat, autopilot=kind) for r in records]
            print(json.dumps(summary[-1]), flush=True)
    (args.out / "runs.jsonl").write_text("".join(json.dumps(r) + "\n" for r in lines))
    (args.out / "config.toml").write_text(text.lstrip())
    (args.out / "summary.json").write_text(json.dumps(summary, indent=1) + "\n")
    print(json.dumps({"runs": len(summary), "all_at_least_4": all(s["touchdowns"] >= 4 for s in summary),
                      "fence_stops": sum(s["fence"] for s in summary)}))


if __name__ == "__main__":
    main()
