"""No sample on stale telemetry, through the console against the SITL (real time): the SITL is
frozen (SIGSTOP) while the person flies; nothing is recorded while it is frozen, the page is told
why the vehicle holds, and the person's steps resume when it runs again (SIGCONT)."""

from __future__ import annotations

import asyncio
import csv
import json
import os
import signal
import time
from pathlib import Path

import aiohttp
import pytest

from companion.experiment.ray_backend import process_children
from companion.msg.observation import OBS_NAMES
from tests.console import start_console, stop
from tests.console.test_console_hold import Page, pad_state

FROZEN_S = 4.0  # beyond link_lost_s (1.5 s): the stale-telemetry hold, then the link-loss path
pytestmark = [pytest.mark.realtime, pytest.mark.e2e, pytest.mark.timeout(300)]


class GapPage(Page):
    """A page that also keeps the ``gap`` messages (why steps are not recorded)."""

    def __init__(self, ws: aiohttp.ClientWebSocketResponse) -> None:
        self.gaps: list[dict | None] = []
        super().__init__(ws)

    def keep(self, m: dict) -> None:
        if m["type"] == "gap":
            self.gaps.append(m["gap"])
        super().keep(m)


def sitl_child(console_pid: int) -> int:
    """The SITL process the console started for its run."""
    for pid in process_children().get(console_pid, []):
        try:
            if b"sitl" in Path(f"/proc/{pid}/cmdline").read_bytes():
                return pid
        except OSError:
            continue
    raise AssertionError(f"no SITL child of the console (pid {console_pid})")


def rows(run_dir: Path) -> list[dict[str, str]]:
    with (run_dir / "human.csv").open(newline="") as f:
        return list(csv.DictReader(f))


async def _scenario(url: str, run_dir: Path, console_pid: int) -> None:
    async with aiohttp.ClientSession() as http:
        page = GapPage(await http.ws_connect(url + "ws"))
        await page.until(lambda: page.hello is not None, 10)
        await page.ws.send_str(json.dumps({"type": "role", "want": "pilot"}))
        await page.ws.send_str(json.dumps({"type": "command", "name": "start", "condition": "int", "episodes": 1}))
        await page.until(lambda: len(page.steps) >= 5, 300)  # an upper bound: the SITL starts slowly at load ~10
        page.state = pad_state(0.5, True)  # take over, fly forward
        await page.until(lambda: sum(s["who"] == "person" for s in page.steps) >= 5, 30)
        sitl = sitl_child(console_pid)
        os.kill(sitl, signal.SIGSTOP)
        try:
            await page.until(lambda: page.gaps and page.gaps[-1] is not None, 30)
            frozen_at = len(rows(run_dir))
            await asyncio.sleep(FROZEN_S)
            after_freeze = len(rows(run_dir))
            told = [g for g in page.gaps if g is not None]
            watcher = GapPage(await http.ws_connect(url + "ws"))  # a page that connects now is told too
            await watcher.until(lambda: watcher.hello is not None, 30)
            status_gap = watcher.hello["status"]["run"]["gap"]  # type: ignore[index]
            await watcher.close()
        finally:
            os.kill(sitl, signal.SIGCONT)
        assert after_freeze == frozen_at, f"{after_freeze - frozen_at} samples recorded while the vehicle was frozen"
        assert {g["kind"] for g in told} <= {"telemetry", "link"} and told[0]["kind"] == "telemetry", told
        assert all(g["holding"] for g in told) and "stale" in told[0]["text"]
        assert status_gap is not None and status_gap["kind"] in ("telemetry", "link")
        # the vehicle runs again: the person's steps resume, recorded, and the page is told
        await page.until(lambda: page.gaps[-1] is None and len(rows(run_dir)) > after_freeze + 5, 60)
        await page.ws.send_str(json.dumps({"type": "command", "name": "stop"}))
        await page.until(lambda: page.status is not None and page.status["run"]["state"] == "finished", 60)
        await page.close()
    recorded = rows(run_dir)
    telemetry = [tuple(r[name] for name in OBS_NAMES[:12]) for r in recorded]
    repeated = sum(a == b for a, b in zip(telemetry, telemetry[1:]))
    assert repeated == 0, f"{repeated} samples share the previous sample's telemetry: recorded on stale telemetry"
    record = json.loads((run_dir / "episodes.jsonl").read_text().splitlines()[0])
    assert any("held on stale telemetry" in n for n in record["notes"]), record["notes"]
    assert record["human_samples"] == len(recorded)


def test_nothing_is_recorded_while_the_vehicle_is_frozen_and_the_page_says_why(tmp_path: Path) -> None:
    run_dir, log = tmp_path / "run", tmp_path / "console.log"
    proc, url = start_console(run_dir, log)
    started = time.monotonic()
    try:
        asyncio.run(_scenario(url, run_dir, proc.pid))
    except BaseException:
        print(f"console log after {time.monotonic() - started:.1f} s:\n{log.read_text()[-6000:]}")
        raise
    finally:
        stop(proc)
