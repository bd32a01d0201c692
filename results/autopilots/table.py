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
    true_on = sum(1 for d in true if d <= 0.5)
    policy, autopilot = path.stem.split("-", 1)
    return (f"| {policy} | {autopilot} | {n} | {touch} | {on_pad} ({100 * on_pad / n:.0f} %, {100 * lo:.0f}-{100 * hi:.0f} %) "
            f"| {statistics.median(est):.2f} | {true_on} of {len(true)} | {statistics.median(true):.2f} |" if est and true else
            f"| {policy} | {autopilot} | {n} | {touch} | {on_pad} | - | - | - |")


def main() -> None:
    root = Path(sys.argv[1])
    print("| policy | autopilot | episodes | touchdowns | on the pad, reported (95 % CI) | median distance, reported (m) "
          "| within 0.5 m, true | median distance, true (m) |")
    print("| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: |")
    for path in sorted([*root.glob("*-px4.jsonl"), *root.glob("*-ardupilot.jsonl"), *root.glob("rerun/*-ardupilot.jsonl")]):
        if path.stat().st_size:
            print(row(path))


if __name__ == "__main__":
    main()
