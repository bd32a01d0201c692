"""The transfer table (docs/camera.md) from the committed episode records, not by hand.

    python results/autopilots/table.py results/autopilots
"""

from __future__ import annotations

import json
import statistics
import sys
from pathlib import Path

from companion.statistics import wilson_interval


def row(path: Path) -> str:
    records = [json.loads(line) for line in path.read_text().splitlines()]
    n = len(records)
    touch = sum(r["outcome"] == "touchdown" for r in records)
    on_pad = sum(1 for r in records if r["success"])
    lo, hi = wilson_interval(on_pad, n)
    est = [r["touchdown_distance_m"] for r in records if r["touchdown_distance_m"] is not None]
    true = [r["true_touchdown_distance_m"] for r in records if r.get("true_touchdown_distance_m") is not None]
    if not true and all(r["success"] is not None for r in records) and "oursitl" in path.stem:
        true = est  # our SITL's distances are its ground truth
    true_on = sum(1 for d in true if d <= 0.5)
    first, second = path.stem.split("-", 1)
    policy, autopilot = (second, "our SITL (lockstep)") if first == "oursitl" else (first, second)
    return (f"| {policy} | {autopilot} | {n} | {touch} | {on_pad} ({100 * on_pad / n:.0f} %, {100 * lo:.0f}-{100 * hi:.0f} %) "
            f"| {statistics.median(est):.2f} | {true_on} of {len(true)} | {statistics.median(true):.2f} |" if est and true else
            f"| {policy} | {autopilot} | {n} | {touch} | {on_pad} | - | - | - |")


def main() -> None:
    root = Path(sys.argv[1])
    print("| policy | autopilot | episodes | touchdowns | on the pad, reported (95 % CI) | median distance, reported (m) "
          "| within 0.5 m, true | median distance, true (m) |")
    print("| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |")
    paths = [*root.glob("oursitl-*.jsonl"), *root.glob("*-px4.jsonl"), *root.glob("*-ardupilot.jsonl"),
             *root.glob("rerun/*-ardupilot.jsonl")]
    for path in sorted(paths, key=lambda p: (p.stem.split("-")[-1], p.stem)):
        if path.stat().st_size:
            print(row(path))


if __name__ == "__main__":
    main()
