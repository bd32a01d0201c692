"""The lead check's table: per motion, expert and pad speed, touchdowns on the pad, timeouts and
the touchdown distance (from the jsonl files beside this script, which run.sh wrote).

    python results/moving-pad/lead-check/summarise.py > results/moving-pad/lead-check/table.md
"""

from __future__ import annotations

import json
import statistics
from pathlib import Path

HERE = Path(__file__).resolve().parent
MOTIONS = {"straight": "straight", "turn": "a curve, 0.1 rad/s", "change": "speed swinging by half, 20 s period"}
EXPERTS = {"lead-off": "the experiment's", "lead-on": "leading", "lead-picture": "leading, set down by the picture"}


def row(lines: list[dict]) -> str:  # type: ignore[type-arg]
    """On the pad of n, timeouts, and the touchdown distance's median and largest."""
    on = sum(1 for d in lines if d["touchdown"] and d["touchdown"]["success"])
    timeouts = sum(1 for d in lines if d["outcome"] == "timeout")
    dist = [d["touchdown"]["distance_to_pad_m"] for d in lines if d["touchdown"]]
    spread = f"{statistics.median(dist):.3f} / {max(dist):.3f}" if dist else "-"
    return f"{on} of {len(lines)} | {timeouts} | {spread}"


def main() -> None:
    print("| pad's motion | expert | pad speed (m/s) | on the pad | timeouts | touchdown distance, median / max (m) |")
    print("| --- | --- | ---: | ---: | ---: | --- |")
    for motion, motion_text in MOTIONS.items():
        for expert, expert_text in EXPERTS.items():
            path = HERE / f"{motion}-{expert}.jsonl"
            if not path.exists():
                continue
            lines = [json.loads(t) for t in path.read_text().splitlines() if t.strip()]
            for speed in sorted({d["pad_speed_m_s"] for d in lines}):
                print(f"| {motion_text} | {expert_text} | {speed} | "
                      f"{row([d for d in lines if d['pad_speed_m_s'] == speed])} |")


if __name__ == "__main__":
    main()
