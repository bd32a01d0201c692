"""Policies trained in our SITL, flown alone on real PX4 SIH and real ArduCopter SITL with the
camera rendered from their telemetry (docs/camera.md).

    python results/autopilots/transfer.py --episodes 20 --out results/autopilots \\
        --policy demo20=CKPT --policy col20=CKPT

Every (policy, autopilot) pair runs at once on its own fresh autopilot instance:
`col eval CKPT --connect ... --episodes N --config config.toml`. Writes, per pair,
`<policy>-<autopilot>.jsonl` (the episode records as `col eval` wrote them) and `summary.json`.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import threading
from pathlib import Path

from companion.statistics import wilson_interval
from companion.testing.autopilots import find_autopilots, start_ardupilot, start_px4

CONFIG = """
[companion.session]
pad_ned_m = [0.0, 0.0, 0.0]  # the pad on the autopilot's own ground; starts as in training: 8 m above it, +-3 m

[companion.perception]
camera = "render"

[sitl.world]
vehicle_height_m = 0.0
"""


def fly(policy: str, checkpoint: Path, kind: str, root: Path, work: Path, config: Path, episodes: int,
        out: Path, results: dict) -> None:
    ap = (start_px4 if kind == "px4" else start_ardupilot)(root, work / f"{policy}-{kind}")
    run_dir = work / f"run-{policy}-{kind}"
    col = str(Path(sys.executable).with_name("col"))
    try:
        done = subprocess.run([col, "eval", str(checkpoint), "--connect", ap.connection, "--episodes", str(episodes),
                               "--config", str(config), "--run-dir", str(run_dir)],
                              capture_output=True, text=True, timeout=3600, stdin=subprocess.DEVNULL)
    finally:
        ap.stop()
    path = run_dir / "episodes.jsonl"
    lines = path.read_text().splitlines() if path.exists() else []
    (out / f"{policy}-{kind}.jsonl").write_text("".join(line + "\n" for line in lines))
    records = [json.loads(line) for line in lines]
    on_pad = sum(1 for r in records if r["success"])
    lo, hi = wilson_interval(on_pad, len(records)) if records else (None, None)
    true = [r["true_touchdown_distance_m"] for r in records if r.get("true_touchdown_distance_m") is not None]
    results[(policy, kind)] = {
        "policy": policy, "autopilot": kind, "checkpoint": str(checkpoint), "episodes": len(records),
        "touchdowns": sum(r["outcome"] == "touchdown" for r in records),
        "on_pad": on_pad, "on_pad_ci95": [lo, hi],
        "true_on_pad": sum(1 for d in true if d <= 0.5), "true_known": len(true),
        "outcomes": [r["outcome"] for r in records], "rc": done.returncode,
    }
    print(json.dumps(results[(policy, kind)]), flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--policy", action="append", required=True, help="NAME=CHECKPOINT")
    parser.add_argument("--episodes", type=int, default=20)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--autopilots", default="px4,ardupilot")
    args = parser.parse_args()
    root, why = find_autopilots()
    if root is None:
        raise SystemExit(why)
    args.out.mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix="transfer-"))
    config = work / "config.toml"
    config.write_text(CONFIG)
    (args.out / "config.toml").write_text(CONFIG.lstrip())
    results: dict = {}
    threads = []
    for spec in args.policy:
        name, _, ckpt = spec.partition("=")
        for kind in args.autopilots.split(","):
            threads.append(threading.Thread(target=fly, args=(name, Path(ckpt), kind, root, work, config,
                                                              args.episodes, args.out, results)))
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    (args.out / "summary.json").write_text(json.dumps(sorted(results.values(), key=lambda r: (r["policy"], r["autopilot"])),
                                                      indent=1) + "\n")


if __name__ == "__main__":
    main()
