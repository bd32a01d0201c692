"""The conformance table of docs/link.md, made from conformance.json (not by hand).

    python results/conformance/table.py results/conformance/conformance.json
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

ROWS = [
    ("take-off mode ACK", "takeoff_mode_ack"),
    ("armable after (s, from the script's start)", "armable_after_s"),
    ("NAV_TAKEOFF ACK", "takeoff_ack"),
    ("climbed (m, of 2.5)", "climbed_m"),
    ("offboard mode ACK", "offboard_ack"),
    ("mode while flying setpoints", "mode_in_offboard"),
    ("landed during 0.26 m/s descent (s)", "landed_at_slow_descent_s"),
    ("landed during 0.33 m/s descent (s)", "landed_at_fast_descent_s"),
    ("disarmed", "disarmed"),
    ("height on the ground before arming (m, -z)", "standing_height_m"),
    ("land-detector parameters", "land_param"),
]


def cell(value: object) -> str:
    if value is None:
        return "no"
    if isinstance(value, dict):
        return ", ".join(f"{k} {v:g}" if isinstance(v, float) else f"{k} {v}" for k, v in value.items())
    return str(value)


def cell_of(outcome: dict, key: str) -> str:
    if key == "landed_at_fast_descent_s" and outcome.get("landed_at_slow_descent_s") is not None:
        return "(landed already)"
    return cell(outcome.get(key))


def main() -> None:
    data = json.loads(Path(sys.argv[1]).read_text())
    out = data["outcomes"]
    for family in ("px4", "ardupilot"):
        real, ours = out[f"real {family}"], out[f"ours {family}"]
        print(f"| {family} | real | ours |\n| --- | --- | --- |")
        for label, key in ROWS:
            print(f"| {label} | {cell_of(real, key)} | {cell_of(ours, key)} |")
        diffs = data["differences"][family]
        print(f"\nDifferences that count ({family}): {'; '.join(diffs) if diffs else 'none'}\n")


if __name__ == "__main__":
    main()
