"""Precision landing against the real autopilots (PX4 SIH, ArduCopter SITL) and our SITL as each.

The same script (companion/testing/conformance.py ``PrecLandScript``) flies all four at once:
(ArduPilot: PLND_ENABLED and PLND_TYPE set, then a reboot), take off to 4 m, send LANDING_TARGET for a fixed point 3 m north and 2 m east of the take-off
place (computed from the vehicle's own reported position), ask for precision landing and see
whether it is accepted, what the HEARTBEAT says, which PLD_* / PLND_* parameters exist, and where
it lands. ``COL_PRECLAND_OUT=FILE`` also writes the outcomes as JSON (results/precland/conformance).

All four run faster than real time (tests/autopilots/__init__.py's ``SPEEDUP``, our SITL as each
at its autopilot's speed): the script's waits count the vehicle's seconds, so it means the same.
"""

from __future__ import annotations

import json
import os
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

from companion.simulator import start_sitl
from companion.testing.autopilots import (
    PX4_LOCAL_PORTS,
    free_udp_port,
    start_ardupilot,
    start_px4,
)
from companion.testing.conformance import PrecLandOutcome, fly_precland
from tests.autopilots import SPEEDUP, autopilots_root
from tests.conftest import ONE_AFTER_ANOTHER

pytestmark = [pytest.mark.realtime, pytest.mark.autopilot, pytest.mark.timeout(600), pytest.mark.xdist_group(ONE_AFTER_ANOTHER)]
KINDS = ("px4", "ardupilot")
NEAR_M = 1.0  # "lands near the point": within this, horizontally, in the vehicle's own frame
# Real PX4 SIH's estimated position wanders 0.3-0.5 m while it approaches and descends, and its
# touchdowns were 0.15-0.76 m from the point over five runs (results/precland/conformance/RUN.md)
# and 1.11 m in the project's CI once (bench/results/ci-project-e3f8488-failed.txt);
# a vertical landing where it stood would be 3.6 m off. Within this it steered to the point.
REAL_PX4_NEAR_M = 1.5


@pytest.fixture(scope="module")
def outcomes(tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict[str, PrecLandOutcome]]:
    root = autopilots_root()
    work = tmp_path_factory.mktemp("precland")
    real = {"px4": start_px4(root, work / "px4", speedup=SPEEDUP["px4"]),
            "ardupilot": start_ardupilot(root, work / "ardupilot", speedup=SPEEDUP["ardupilot"])}
    config = work / "ours.toml"
    config.write_text("[sitl.personality]\nprearm_settle_s = 4.0\n")
    ours = {}
    connections = {f"real {k}": ap.connection for k, ap in real.items()}
    for kind in KINDS:
        port = free_udp_port()
        ours[kind] = start_sitl(port, clock="realtime", config=config, camera=False, timeout_s=120.0,
                                extra_args=["--autopilot", kind, "--speed", f"{SPEEDUP[kind]:g}"])
        connections[f"ours {kind}"] = f"udpin:127.0.0.1:{port}"
    results: dict[str, PrecLandOutcome] = {}
    # PX4 says nothing on its API link: listen as a ground station on its GCS link (local port 18570 + i)
    texts_from = {"real px4": f"udpout:127.0.0.1:{PX4_LOCAL_PORTS[1] + real['px4'].instance}"}

    def fly(name: str) -> None:
        try:
            results[name] = fly_precland(connections[name], texts_from=texts_from.get(name))
        except Exception as exc:  # reported by the tests
            results[name] = PrecLandOutcome(errors=[repr(exc)])

    try:
        threads = [threading.Thread(target=fly, args=(name,)) for name in connections]
        for t in threads:
            t.start()
        for t in threads:
            t.join(500)
        out = os.environ.get("COL_PRECLAND_OUT")
        if out:
            Path(out).parent.mkdir(parents=True, exist_ok=True)
            Path(out).write_text(json.dumps({k: v.to_dict() for k, v in sorted(results.items())}, indent=1) + "\n")
        yield results
    finally:
        for ap in real.values():
            ap.stop()
        for sitl in ours.values():
            sitl.stop()


@pytest.mark.parametrize("kind", KINDS)
def test_the_real_autopilot_accepts_the_precision_landing_request_and_has_the_parameters(
        outcomes: dict[str, PrecLandOutcome], kind: str) -> None:
    real = outcomes[f"real {kind}"]
    assert not real.errors and real.armed, real
    assert real.mode_ack == "ACCEPTED", real
    assert all(v is not None for v in real.params.values()), real.params
    want = "(main 4, sub 9)" if kind == "px4" else "LAND"
    assert want in real.mode_in_heartbeat, real


@pytest.mark.parametrize("kind", KINDS)
def test_our_sitl_answers_and_lands_as_the_real_autopilot_does(outcomes: dict[str, PrecLandOutcome], kind: str) -> None:
    real, ours = outcomes[f"real {kind}"], outcomes[f"ours {kind}"]
    assert not ours.errors, ours
    assert (ours.mode_ack, ours.mode_in_heartbeat) == (real.mode_ack, real.mode_in_heartbeat), (real, ours)
    assert ours.reboot_ack == real.reboot_ack, (real, ours)  # ArduPilot: PLND_TYPE needs the reboot
    assert set(ours.params) == set(real.params) and all(v is not None for v in ours.params.values()), ours.params
    for outcome, near_m in ((real, REAL_PX4_NEAR_M if kind == "px4" else NEAR_M), (ours, NEAR_M)):
        # both land near the point the LANDING_TARGETs name
        assert outcome.touchdown_from_point_m is not None and outcome.touchdown_from_point_m < near_m, (real, ours)


@pytest.mark.parametrize("kind", KINDS)
def test_a_target_in_the_other_autopilots_frame_is_refused_as_the_real_one_refuses_it(
        outcomes: dict[str, PrecLandOutcome], kind: str) -> None:
    """PX4 takes only LOCAL_NED positions, ArduPilot only BODY_FRD: each says so (or not) alike."""
    real, ours = outcomes[f"real {kind}"], outcomes[f"ours {kind}"]
    said = [bool([t for t in o.wrong_frame_texts if "rame" in t]) for o in (real, ours)]
    assert said[0] == said[1], (real.wrong_frame_texts, ours.wrong_frame_texts)
