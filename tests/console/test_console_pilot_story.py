"""``col console`` against the SITL in Debian's chromium, as a pilot would meet it: a second tab
watches (and is told so) while the first keeps the pilot role; a broken pad's NaN and 1e308
sticks are refused at the socket and never recorded; a demonstration with nobody on the sticks
is flagged and discarded (an audit line, nothing deleted); the next episode waits for the
pilot's Go; and a console restarted on the run folder shows the history."""

from __future__ import annotations

import csv
import json
import signal
import time
from pathlib import Path

import pytest

from companion.learning.dataset import HumanDataset
from tests.conftest import ONE_AFTER_ANOTHER
from tests.console import start_console, stop
from tests.console.test_console_browser import FAKE_PAD, _browser_or_skip, _wait, chromium, shot

pytestmark = [pytest.mark.realtime, pytest.mark.e2e, pytest.mark.xdist_group(ONE_AFTER_ANOTHER), pytest.mark.timeout(1500)]
PITCH = 0.3  # the good stick before the pad breaks: every recorded row must carry exactly it


def _open(context, url: str):  # type: ignore[no-untyped-def]
    page = context.new_page()
    page.add_init_script(FAKE_PAD)
    page.on("dialog", lambda dialog: dialog.accept())  # "take episode N out of training?"
    page.goto(url)
    _wait(page, "window.colConsole.hello !== null && window.colConsole.role !== null", 20)
    return page


def _two_tabs_and_a_broken_pad(context, url: str, tmp_path: Path):  # type: ignore[no-untyped-def]
    a = _open(context, url)
    a.click("#take-role")
    _wait(a, "window.colConsole.role.role === 'pilot'", 10)
    a.select_option("#condition", "demo")
    a.fill("#episodes", "2")
    a.click("#start")
    a.evaluate(f"window.__pad.axes[3] = {-PITCH}")
    _wait(a, "window.colConsole.lastStep !== null && window.colConsole.lastStep.recorded", 120)

    b = _open(context, url)  # a second tab on the same URL
    assert b.evaluate("window.colConsole.role.role") == "watch"
    assert "is the pilot" in b.inner_text("#banner") and b.is_disabled("#stop") and b.is_disabled("#start")
    shot(b, tmp_path, "console_watching.png")
    # even a page that thinks it may (in one task, before the server corrects its role): refused, and told.
    # A page the server dropped at load (it fell MAX_QUEUED messages behind) reconnects within a second
    # and has no role meanwhile; the forgery waits for it in the same task, as a page would.
    b.evaluate("""async () => {
      const C = window.colConsole;
      while (!(C.connected && C.role)) await new Promise((done) => setTimeout(done, 50));
      C.role.role = 'pilot'; const stop = document.getElementById('stop'); stop.disabled = false; stop.click();
    }""")
    _wait(b, "window.colConsole.errors.some((e) => e.text.includes('only the pilot'))", 10)
    _wait(b, "window.colConsole.role.role === 'watch' && document.getElementById('stop').disabled", 10)  # told again
    assert a.evaluate("window.colConsole.role.role") == "pilot"
    # the status is broadcast four times a second after a ground-truth request to the SITL: read
    # at one instant it was once still `starting` after the first recorded steps (docs/console.md)
    _wait(a, "window.colConsole.status.run.state === 'running'", 10)

    a.evaluate("window.__pad.axes[0] = NaN; window.__pad.axes[1] = 1e308; window.__pad.axes[2] = -Infinity;"
               "window.__pad.axes[3] = 5")
    _wait(a, "window.colConsole.errors.some((e) => e.text.startsWith('input refused'))", 10)
    _wait(a, "window.colConsole.lastStep.who === 'hold'", 20)  # the good input aged out: the vehicle holds
    shot(a, tmp_path, "console_refused_input.png")
    _wait(b, "window.colConsole.lastStep.who === 'hold'", 20)  # the watcher sees the hold and still who flies
    assert "HOLDING POSITION" in b.inner_text("#banner") and "is the pilot" in b.inner_text("#banner")
    b.close()
    a.evaluate("window.__pad.axes.fill(0)")
    return a


def _the_flagged_demonstration(a, tmp_path: Path) -> dict:  # type: ignore[no-untyped-def]
    a.click("#next")  # episode 0 ends; episode 1 waits at the ready gate
    _wait(a, "window.colConsole.status.run.state === 'ready' && window.colConsole.records.length === 1", 60)
    a.evaluate("window.__clicks = []; document.addEventListener('click', (e) => window.__clicks.push("
               "[e.target.id || e.target.tagName, e.clientX, e.clientY]), true)")
    a.click("#go")  # nobody touches the sticks in episode 1
    try:
        _wait(a, "window.colConsole.status.run.state !== 'ready'", 15)
    except Exception:  # what the page clicked, and where the button was
        print("clicks", a.evaluate("window.__clicks"), "go at", a.evaluate(
            "JSON.stringify(document.getElementById('go').getBoundingClientRect())"), "connected",
            a.evaluate("window.colConsole.connected"), "role", a.evaluate("JSON.stringify(window.colConsole.role)"))
        shot(a, tmp_path, "console_go_lost.png")
        raise
    _wait(a, "window.colConsole.status.run.state === 'running' && window.colConsole.lastStep.episode === 1"
             " && window.colConsole.lastStep.step >= 15", 120)
    a.click("#next")
    _wait(a, "window.colConsole.records.length === 2 && window.colConsole.status.run.state === 'finished'", 60)
    record = a.evaluate("window.colConsole.records[1]")
    assert record["no_stick_input"] and "no stick input" in a.inner_text("#episodes-table")
    a.click("#discard")
    _wait(a, "window.colConsole.records[1].discarded !== null", 10)
    return record


def test_two_tabs_bad_sticks_a_discarded_episode_and_the_history_after_a_restart(tmp_path: Path) -> None:
    _browser_or_skip()  # before the console starts

    run_dir, log = tmp_path / "run", tmp_path / "console.log"
    proc, url = start_console(run_dir, log, "--no-pictures", "-v")
    try:
        with chromium(tmp_path / "profile") as context:
            try:
                a = _two_tabs_and_a_broken_pad(context, url, tmp_path)
                seen = a.evaluate("window.colConsole.steps")
                record = _the_flagged_demonstration(a, tmp_path)
                _wait(a, "window.colConsole.videoState === 'idle' && window.colConsole.hudState === 'idle'", 10)
                shot(a, tmp_path, "console_discarded.png")
            except Exception:  # where the page and every thread of the console were, for the report
                for page in context.pages:
                    print("page status", page.evaluate("JSON.stringify(window.colConsole && window.colConsole.status)"))
                proc.send_signal(signal.SIGUSR1)
                time.sleep(1.0)
                raise
    finally:
        stop(proc)
        print(log.read_text()[-20000:])  # pytest shows it when the test fails: what the console logged
    text = log.read_text()
    assert "refused a message: input refused" in text
    with (run_dir / "human.csv").open() as f:
        rows = list(csv.DictReader(f))
    ep0 = [r for r in rows if r["episode"] == "0"]
    held = [s["step"] for s in seen if s["who"] == "hold" and s["episode"] == 0]
    assert held, "the refused sticks did not make the vehicle hold"
    sticks = {int(r["step"]): tuple(float(r[k]) for k in ("roll", "pitch", "yaw", "throttle")) for r in ep0}
    # before the last hold: only the good stick (a page stalled by a busy machine may make the
    # vehicle hold earlier too, its good input aged out; never a refused stick recorded)
    before = [v for step, v in sticks.items() if step < held[-1]]
    after = [v for step, v in sticks.items() if step > held[-1]]  # the pad repaired: centred sticks
    assert before and all(v == pytest.approx((0.0, PITCH, 0.0, 0.0)) for v in before), "a refused stick was recorded"
    assert all(v == (0.0, 0.0, 0.0, 0.0) for v in after) and not set(held) & set(sticks)
    assert len(before) + len(after) == len(ep0)
    ep1 = [r for r in rows if r["episode"] == "1"]
    assert len(ep1) == record["human_samples"] > 0  # the discarded rows stay in the file ...
    audit = [json.loads(x) for x in (run_dir / "human.discarded.jsonl").read_text().splitlines()]
    assert audit == [{**audit[0], "episode": 1, "rows": len(ep1)}]
    with HumanDataset(run_dir / "human.csv") as ds:  # ... and out of training
        assert len(ds) == len(ep0)

    proc, url = start_console(run_dir, log, "--no-pictures", "-v")  # the console restarted on the same folder
    try:
        with chromium(tmp_path / "profile2") as context:
            page = _open(context, url)
            records = page.evaluate("window.colConsole.records")
            assert [r["episode"] for r in records] == [0, 1] and records[1]["discarded"]
            assert "discarded" in page.inner_text("#episodes-table")
            _wait(page, "window.colConsole.videoState === 'no-video'", 10)
            shot(page, tmp_path, "console_history.png")
    finally:
        stop(proc)
