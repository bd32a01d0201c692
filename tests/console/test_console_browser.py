"""``col console`` driven by a person's stand-in in a real headless browser (Debian's chromium
through Playwright): the page loads, camera frames are drawn, an emulated Xbox pad (the page's
``navigator.getGamepads``) pushes the right stick forward and holds the trigger, the SITL's
ground truth shows the vehicle moving forward, and exactly the steps flown by the person are
in ``human.csv``, tagged as interventions."""

from __future__ import annotations

import contextlib
import csv
import math
import os
import shutil
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import pytest

from companion.simulator import SimulatorClient
from tests.conftest import ONE_AFTER_ANOTHER
from tests.console import start_console, stop

CHROMIUM = os.environ.get("COL_CHROMIUM") or shutil.which("chromium") or "/usr/bin/chromium"
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync",
                 # a tab opened beside the pilot's must not slow the pilot's input timer to 1 Hz
                 # (chromium throttles background tabs; a real pilot who switches tabs gets the hold)
                 "--disable-background-timer-throttling", "--disable-renderer-backgrounding",
                 "--disable-backgrounding-occluded-windows"]

# An Xbox pad in the Gamepad API's standard layout whose state the test sets through window.__pad.
FAKE_PAD = """
window.__pad = {axes: [0, 0, 0, 0], buttons: new Array(17).fill(0)};
navigator.getGamepads = () => [{
  id: "Emulated Xbox pad (STANDARD GAMEPAD)", index: 0, connected: true, mapping: "standard",
  timestamp: performance.now(), axes: window.__pad.axes.slice(),
  buttons: window.__pad.buttons.map((v) => ({pressed: v > 0.5, touched: v > 0, value: v})),
}];
"""

pytestmark = [pytest.mark.realtime, pytest.mark.e2e, pytest.mark.xdist_group(ONE_AFTER_ANOTHER), pytest.mark.timeout(900)]
SHOTS = os.environ.get("COL_CONSOLE_SHOTS")  # a folder: keep the screenshots (docs/images)


def shot(page, tmp_path: Path, name: str) -> None:  # type: ignore[no-untyped-def]
    """A screenshot of the page, into COL_CONSOLE_SHOTS when set (else the test's folder)."""
    page.screenshot(path=str(Path(SHOTS) / name if SHOTS else tmp_path / name), full_page=True)


def _browser_or_skip() -> None:
    if not os.path.exists(CHROMIUM):
        pytest.skip("chromium is not installed (Debian: apt-get install -y chromium); the console's "
                    "browser test needs a real browser")
    pytest.importorskip("playwright.sync_api", reason="playwright is not installed (pip install '.[test]')")


@contextlib.contextmanager
def chromium(profile: Path, extra: Sequence[str] = ()) -> Iterator[Any]:
    """Headless chromium with its own profile folder (``extra``: more command-line switches) as a
    Playwright browser context, closed after the block; the test is skipped without chromium."""
    _browser_or_skip()
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        context = pw.chromium.launch_persistent_context(str(profile), executable_path=CHROMIUM, headless=True,
                                                        args=[*CHROMIUM_ARGS, *extra],
                                                        viewport={"width": 1280, "height": 900})
        try:
            yield context
        finally:
            context.close()


@pytest.fixture
def console(tmp_path: Path) -> Iterator[tuple[str, Path]]:
    """A running ``col console`` on a free port: (its URL, its run folder)."""
    run_dir = tmp_path / "run"
    proc, url = start_console(run_dir, tmp_path / "console.log")
    try:
        yield url, run_dir
    finally:
        stop(proc)
        print((tmp_path / "console.log").read_text()[-6000:])  # shown when the test fails


PATIENCE = 4.0
"""Every wait is an upper bound, stretched for a machine at load ~10 (the first control step
alone took over 90 s beside six busy processes on 2 cores); a healthy run passes in seconds."""


def _wait(page, expression: str, timeout_s: float) -> object:  # type: ignore[no-untyped-def]
    page.wait_for_function(expression, timeout=timeout_s * PATIENCE * 1000)
    return page.evaluate(expression)


def _forward_ne(yaw_rad: float) -> tuple[float, float]:
    return math.cos(yaw_rad), math.sin(yaw_rad)


def test_a_person_in_the_browser_intervenes_and_exactly_their_steps_are_recorded(console, tmp_path: Path) -> None:
    url, run_dir = console
    with chromium(tmp_path / "profile") as context:
        page = context.pages[0] if context.pages else context.new_page()
        page.add_init_script(FAKE_PAD)
        page.goto(url)
        _wait(page, "window.colConsole.hello !== null", 20)
        page.click("#take-role")  # this page asks to be the pilot and is told it is
        _wait(page, "window.colConsole.role.role === 'pilot'", 10)
        assert "gamepad: Emulated Xbox pad" in page.inner_text("#pad-state")

        # as a person would: choose Int, one episode, press Start
        page.select_option("#condition", "int")
        page.fill("#episodes", "1")
        page.click("#start")
        _wait(page, "window.colConsole.lastStep !== null && window.colConsole.lastStep.step >= 5", 90)
        step = page.evaluate("window.colConsole.lastStep")
        assert step["phase"] == "intervention" and step["who"] == "policy"

        frames0 = page.evaluate("window.colConsole.framesDrawn")
        # the video keeps coming (its rate is bench/console.py's figure, not a test's)
        _wait(page, f"window.colConsole.framesDrawn >= {frames0 + 10}", 30)

        sim = SimulatorClient(*page.evaluate("window.colConsole.status.simulator").split(":"))
        try:
            before = sim.truth()
            # right stick forward (y = -0.8 is up) with the right trigger held
            page.evaluate("window.__pad.axes[3] = -0.8; window.__pad.buttons[7] = 1.0")
            _wait(page, "window.colConsole.lastStep.who === 'person'", 10)
            first = page.evaluate("window.colConsole.lastStep")
            # 30 control steps and 3 s of the vehicle's own time on the person's stick, however
            # long a busy machine takes to fly them (a starved SITL's clock runs slow; a step on
            # its stale telemetry holds and is neither shown nor recorded)
            _wait(page, f"(() => {{ const p = window.colConsole.steps.filter((s) => s.who === 'person'"
                        f" && s.step >= {first['step']}); return p.length >= 30"
                        f" && p[p.length - 1].timeBootMs - {first['time_boot_ms']} >= 3000; }})()", 120)
            after = sim.truth()
            shot(page, tmp_path, "console_intervening.png")
            page.evaluate("window.__pad.axes[3] = 0; window.__pad.buttons[7] = 0")
            _wait(page, "window.colConsole.lastStep.who === 'policy'", 10)
        finally:
            sim.close()
        yaw = before["attitude_rad"][2]
        fwd = _forward_ne(yaw)
        dn = after["vehicle_ned"][0] - before["vehicle_ned"][0]
        de = after["vehicle_ned"][1] - before["vehicle_ned"][1]
        along, across = dn * fwd[0] + de * fwd[1], -dn * fwd[1] + de * fwd[0]
        assert along > 1.5, (f"pushed forward for 3 s of the vehicle's time but moved only {along:.2f} m forward "
                             f"({dn:.2f} N, {de:.2f} E)")
        assert abs(across) < 0.5 * along

        page.click("#stop")
        _wait(page, "window.colConsole.status.run.state === 'finished'", 60)
        _wait(page, "window.colConsole.records.length === 1", 10)
        seen = page.evaluate("window.colConsole.steps")
        record = page.evaluate("window.colConsole.records[0]")
        shot(page, tmp_path, "console_finished.png")

    person_steps = sorted(s["step"] for s in seen if s["who"] == "person")
    assert person_steps, "the page never showed the person flying"
    assert all(s["recorded"] and s["tag"] == "intervention" for s in seen if s["who"] == "person")
    assert not any(s["recorded"] for s in seen if s["who"] != "person")
    with (run_dir / "human.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert sorted(int(r["step"]) for r in rows) == person_steps
    assert {r["source"] for r in rows} == {"intervention"}
    # one continuous intervention: no step between the person's first and last flown by the policy
    # (a busy machine may hold a tick; a step on stale telemetry is not shown at all)
    taken = sorted(s["step"] for s in seen if s["who"] in ("person", "hold"))
    assert all(s["who"] in ("person", "hold") for s in seen if taken[0] <= s["step"] <= taken[-1])
    assert len(person_steps) >= 20  # 3 s held at 10.5 Hz, with slack for a busy machine
    for r in rows:  # the stick as pushed: pitch forward only (deadband and expo act later)
        assert float(r["pitch"]) == pytest.approx(0.8, abs=1e-6)
        assert float(r["roll"]) == float(r["yaw"]) == float(r["throttle"]) == 0.0
    assert record["interventions"] == 1 and record["human_samples"] == len(rows)
    # The policy has learned only the person's "forward" and flies on after the release; on a busy
    # machine the Stop may come after it reached the fence. Either way the episode ended after the
    # intervention, and not on an error.
    assert record["outcome"] in ("stopped", "touchdown", "timeout", "fence")
    if record["outcome"] == "fence":
        assert record["steps"] > person_steps[-1] + 1
    assert (run_dir / "flight_000-000.png").is_file() and (run_dir / "episode_000.mp4").is_file()
