"""The console's page in Debian's chromium (Playwright) against the console's server in this
process, with no vehicle: a page reached through a rebound name is refused, and the video says
when frames stop arriving (stale) and when no run flies (idle)."""

from __future__ import annotations

import asyncio
import threading
from pathlib import Path

import numpy as np
import pytest
from aiohttp import web

from colcommon.frames import Frame
from companion.console.frames import encode_for_page
from companion.console.server import ConsoleServer
from tests.conftest import ONE_AFTER_ANOTHER
from tests.console.test_console_browser import _wait, chromium, shot

pytestmark = [pytest.mark.realtime, pytest.mark.e2e, pytest.mark.xdist_group(ONE_AFTER_ANOTHER), pytest.mark.timeout(180)]


class Served:
    """A ConsoleServer on a free loopback port, on its own thread and event loop."""

    def __init__(self, server: ConsoleServer) -> None:
        self.server, self.port = server, 0
        self.loop = asyncio.new_event_loop()
        self._ready, self._stop = threading.Event(), asyncio.Event()
        self.thread = threading.Thread(target=self.loop.run_until_complete, args=(self._main(),), daemon=True)
        self.thread.start()
        assert self._ready.wait(30), "the console's server did not start"

    async def _main(self) -> None:
        runner = web.AppRunner(self.server.app, handle_signals=False)
        await runner.setup()
        site = web.TCPSite(runner, "127.0.0.1", 0)
        await site.start()
        self.port = int(runner.addresses[0][1])
        self._ready.set()
        await self._stop.wait()
        await runner.cleanup()

    def close(self) -> None:
        self.loop.call_soon_threadsafe(self._stop.set)
        self.thread.join(30)


def test_a_page_reached_through_a_rebound_name_is_refused(served: Served, tmp_path: Path) -> None:
    with chromium(tmp_path / "profile", ["--host-resolver-rules=MAP attacker.example 127.0.0.1"]) as context:  # attacker.example resolves to 127.0.0.1, as a rebinding DNS makes it
        page = context.new_page()
        response = page.goto(f"http://attacker.example:{served.port}/")
        assert response is not None and response.status == 403
        assert "answers to its own names only" in page.inner_text("body")
        opened = page.evaluate(f"""() => new Promise((done) => {{
            const ws = new WebSocket("ws://attacker.example:{served.port}/ws");
            ws.onopen = () => done("open"); ws.onerror = () => done("refused"); }})""")
        assert opened == "refused" and not served.server.clients
        own = context.new_page()
        own.goto(f"http://127.0.0.1:{served.port}/")
        _wait(own, "window.colConsole.hello !== null", 20)


def _frame(n: int) -> bytes:
    image = np.full((240, 320, 3), 90, np.uint8)
    image[100:140, 140 + n % 20: 180 + n % 20] = 230
    return encode_for_page(Frame(n, 1000 + 28 * n, image))


def test_the_video_says_when_frames_stop_and_when_no_run_flies(served: Served, tmp_path: Path) -> None:
    session = served.server.session
    with chromium(tmp_path / "profile") as context:
        page = context.new_page()
        page.goto(f"http://127.0.0.1:{served.port}/")
        _wait(page, "window.colConsole.hello !== null", 20)
        assert page.evaluate("window.colConsole.videoState") == "no-video"
        session._run.state = "running"  # a run as the page sees it (status 4 times a second)
        _wait(page, "window.colConsole.status.run.state === 'running'", 20)
        for n in range(3):  # one at a time: a page is sent only the newest frame waiting for it
            served.server.publish_frame(_frame(n))
            _wait(page, f"window.colConsole.framesDrawn === {n + 1}", 20)
        page.evaluate("window.colConsole.clockOffsetMs = 0")  # frames now stop arriving
        _wait(page, "window.colConsole.videoState === 'stale'", 30)
        shot(page, tmp_path, "console_stale.png")
        served.server.publish_frame(_frame(3))
        _wait(page, "window.colConsole.videoState === 'live'", 20)
        session._run.state = "finished"
        _wait(page, "window.colConsole.videoState === 'idle' && window.colConsole.hudState === 'idle'", 20)
