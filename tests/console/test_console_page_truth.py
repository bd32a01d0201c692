"""The page tells the truth (Debian's chromium through Playwright, the console's server in this
process, no vehicle; the test plays the control loop): the hold banner names why the vehicle
holds (a vehicle-side gap, refused sticks, the pilot's role given up), a pad that is not a pad
is refused with a counted error and never fed, the keyboard still flies, and a page whose
console is gone says so with its controls off."""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

import pytest

from companion.control.gaps import STALE_TELEMETRY, VIDEO_MISSING
from tests.conftest import ONE_AFTER_ANOTHER
from tests.console.test_console_browser import FAKE_PAD, PATIENCE, _wait, chromium, shot
from tests.console.test_console_pages import Served

pytestmark = [pytest.mark.realtime, pytest.mark.e2e, pytest.mark.xdist_group(ONE_AFTER_ANOTHER), pytest.mark.timeout(240)]
C = "window.colConsole"


def _until(test: Callable[[], bool], timeout_s: float, what: str) -> None:
    """Wait for a state of the server (stretched like the page's waits, for a loaded machine)."""
    deadline = time.monotonic() + timeout_s * PATIENCE
    while not test():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.02)


def _pilot(page, port: int) -> None:  # type: ignore[no-untyped-def]
    page.goto(f"http://127.0.0.1:{port}/")
    _wait(page, f"{C}.hello !== null && {C}.role !== null", 20)
    page.click("#take-role")
    _wait(page, f"{C}.role.role === 'pilot'", 10)


BANNER = "(() => { const b = document.getElementById('banner'); return b.classList.contains('hidden') ? '' : b.textContent; })()"


def _flying(context, served: Served):  # type: ignore[no-untyped-def]
    """The pilot's page with the emulated pad, a run "running", the stick forward, the trigger held."""
    page = context.new_page()
    page.add_init_script(FAKE_PAD)
    _pilot(page, served.port)
    served.server.session._run.state = "running"  # a run as the page sees it; the test plays its control loop
    _wait(page, f"{C}.status.run.state === 'running'", 20)
    page.evaluate("window.__pad.axes[3] = -0.5; window.__pad.buttons[7] = 1.0")
    human = served.server.session.human
    _until(lambda: human.status().fresh and human.status().command.override_held, 10, "the pad's sticks")
    return page


def test_the_banner_names_the_vehicles_side_holding_or_not_recorded(served: Served, tmp_path: Path) -> None:
    session = served.server.session
    with chromium(tmp_path / "profile") as context:
        page = _flying(context, served)
        session.on_gap(STALE_TELEMETRY)  # stale telemetry: the vehicle holds
        _wait(page, f"{BANNER}.startsWith('HOLDING POSITION: ' + {STALE_TELEMETRY.text!r})", 10)
        assert "lost its link" not in page.inner_text("#banner")
        session.on_gap(VIDEO_MISSING)  # no video frame: steps fly on, not recorded
        _wait(page, f"{BANNER}.startsWith('NOT RECORDED: ' + {VIDEO_MISSING.text!r})", 10)
        assert "HOLDING" not in page.inner_text("#banner")
        session.on_gap(None)
        _wait(page, f"{BANNER} === ''", 10)


def test_a_pad_that_is_not_a_pad_is_refused_counted_and_named_by_the_hold(served: Served, tmp_path: Path) -> None:
    human = served.server.session.human
    with chromium(tmp_path / "profile") as context:
        page = _flying(context, served)
        page.evaluate("window.__pad.axes = [0, -0.5]")  # the pad loses its right stick
        refused = f"{C}.errors.find((e) => !e.dismissed && e.text.startsWith('this gamepad reports 2 axes'))"
        _wait(page, f"!!{refused} && {refused}.count >= 3", 20)  # counted, never centred sticks
        fed = human.status().messages
        assert "(x" in page.inner_text("#errors") and "not the standard layout" in page.inner_text("#pad-state")
        count = page.evaluate(f"{refused}.count")
        _wait(page, f"{refused}.count > {count}", 20)  # it goes on counting ...
        assert human.status().messages == fed  # ... and nothing of it reached the session
        page.click("#errors .error button")  # Dismiss: the same fault is shown again, counted on
        _wait(page, f"!!{refused} && {refused}.count > {count}", 20)

        _until(lambda: not human.status().fresh, 10, "the last good input to age out")
        assert human.read().hold  # the control loop's next step: a latched hold, and why
        _wait(page, f"{BANNER}.startsWith(\"HOLDING POSITION: the pilot's input is refused (this gamepad "
                    "reports 2 axes\")", 10)
        banner = page.inner_text("#banner")
        assert "lost its link" not in banner and "Hand back to policy" in banner
        assert page.inner_text("#link") == "connected"
        shot(page, tmp_path, "console_refused_pad.png")
        page.click("#take-role")  # this page gives the role up; the keyboard's page takes it

        keys = context.new_page()  # no gamepad: the keyboard is a whole pad (4 axes, 8 buttons)
        _pilot(keys, served.port)
        assert "keyboard" in keys.inner_text("#pad-state")
        keys.bring_to_front()
        keys.click("#video")
        keys.keyboard.down("w")
        keys.keyboard.down(" ")
        _until(lambda: human.status().fresh and human.status().command.override_held
               and human.status().command.command.throttle > 0.5, 10, "the keyboard's sticks")
        assert not human.read().hold  # the person has the sticks again: the latch is released
        _wait(keys, f"{BANNER} === ''", 10)
        assert keys.evaluate(f"{C}.errors.length") == 0
        keys.keyboard.up(" ")
        keys.keyboard.up("w")


def test_the_banner_says_the_pilot_gave_up_the_role(served: Served, tmp_path: Path) -> None:
    human = served.server.session.human
    with chromium(tmp_path / "profile") as context:
        page = _flying(context, served)
        page.click("#take-role")  # "Give up the pilot role" with the trigger held
        _wait(page, f"{C}.role.role === 'watch'", 10)
        assert human.read().hold
        page_number = page.evaluate(f"{C}.role.page")
        _wait(page, f"{BANNER}.startsWith('HOLDING POSITION: the pilot (page {page_number}) gave up the role "
                    "while the person held the override')", 10)
        assert "lost its link" not in page.inner_text("#banner") and "nobody is the pilot" in page.inner_text("#banner")


def test_a_page_whose_console_is_gone_says_so_and_turns_its_controls_off(served: Served, tmp_path: Path) -> None:
    with chromium(tmp_path / "profile") as context:
        page = context.new_page()
        _pilot(page, served.port)
        served.server.session._run.state = "running"
        _wait(page, f"{C}.status.run.state === 'running' && !document.getElementById('stop').disabled", 20)
        assert "PILOT" in page.inner_text("#role")
        served.close()  # the console stops
        _wait(page, f"{BANNER}.startsWith('NO CONSOLE: this page cannot reach the console')", 30)
        assert page.inner_text("#link") == "no console"
        assert "PILOT" not in page.inner_text("#role")
        assert page.inner_text("#run-state").startswith("not connected") and "last known: running" in page.inner_text("#run-state")
        for control in ("#stop", "#pause", "#start", "#take-role", "#condition", "#episodes", "#auto"):
            assert page.is_disabled(control), control
        assert page.evaluate("document.body.classList.contains('offline')")
        assert page.evaluate(f"{C}.videoState") == "offline"
        shot(page, tmp_path, "console_gone.png")
