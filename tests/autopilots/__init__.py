"""Tests against the real autopilots (PX4 SIH, ArduCopter SITL).

:data:`SPEEDUP`: how many times faster than real time the modules here run each autopilot, and
our SITL as it. Chosen from what was measured on the 2-core machine (bench/README.md, "The real
autopilots faster than real time"), with margin for CI's load. ``COL_AUTOPILOT_SPEEDUP``
(``px4=8,ardupilot=10``) overrides it, to measure that margin.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from companion.testing.autopilots import find_autopilots


def _speedups(text: str) -> dict[str, float]:
    """``kind=N`` pairs, comma-separated."""
    pairs = (item.split("=") for item in text.split(",") if item.strip())
    return {kind.strip(): float(value) for kind, value in pairs}


SPEEDUP = {"px4": 4.0, "ardupilot": 5.0} | _speedups(os.environ.get("COL_AUTOPILOT_SPEEDUP", ""))


def autopilots_root() -> Path:
    """The prebuilt autopilots' folder; without it the test skips and says how to get them, or
    fails where ``COL_REQUIRE_AUTOPILOTS=1`` (set by .ci/run)."""
    root, why = find_autopilots()
    if root is None:
        if os.environ.get("COL_REQUIRE_AUTOPILOTS") == "1":
            pytest.fail(why)
        pytest.skip(why)
    return root
