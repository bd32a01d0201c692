"""The console's server without a vehicle: the page and its files, the WebSocket's messages,
refused requests, and which page is the pilot."""

from __future__ import annotations

import asyncio
from pathlib import Path

from aiohttp.test_utils import TestClient, TestServer

from companion.config import CompanionConfig
from companion.console.server import ConsoleServer
from companion.console.session import ConsoleOptions, ConsoleSession

INPUT = {"type": "input", "axes": [0, 0, 0, -0.5], "buttons": [0] * 7 + [1], "seq": 0, "t": 0}


def make_server(tmp_path: Path) -> ConsoleServer:
    cfg = CompanionConfig()
    return ConsoleServer(lambda publish, frame: ConsoleSession(cfg, ConsoleOptions(run_dir=tmp_path / "run"), publish, frame))


async def _until(test, timeout_s: float = 3.0) -> bool:  # type: ignore[no-untyped-def]
    for _ in range(int(timeout_s / 0.01)):
        if test():
            return True
        await asyncio.sleep(0.01)
    return bool(test())


async def _next_of(ws, kind: str) -> dict:  # type: ignore[no-untyped-def]
    while True:
        message = await asyncio.wait_for(ws.receive_json(), 5.0)
        if message["type"] == kind:
            return message


async def _scenario(tmp_path: Path) -> None:
    server = make_server(tmp_path)
    human = server.session.human
    async with TestServer(server.app, host="127.0.0.1") as ts, TestClient(ts) as client:
        page = await client.get("/")
        assert page.status == 200 and "pilot console" in await page.text()
        for name in ("console.js", "console.css", "index.html"):
            assert (await client.get(f"/static/{name}")).status == 200
        assert (await client.get("/static/secret.py")).status == 404

        first = await client.ws_connect("/ws")
        hello = await _next_of(first, "hello")
        assert hello["conditions"] == ["demo", "int", "col"] and hello["control_rate_hz"] == 10.5
        assert hello["status"]["run"]["state"] == "idle" and hello["records"] == []

        for bad, why in [({"type": "command", "name": "start", "condition": "eval", "episodes": 1}, "condition"),
                         ({"type": "command", "name": "start", "condition": "col", "episodes": 0}, "episodes"),
                         ({"type": "command", "name": "fly"}, "unknown command"),
                         ({"type": "dance"}, "unknown message type"),
                         ({"type": "input", "axes": 1, "buttons": []}, "axes")]:
            await first.send_json(bad)
            assert why in (await _next_of(first, "error"))["message"]
        await first.send_str("[1, 2]")
        assert "JSON object" in (await _next_of(first, "error"))["message"]

        await first.send_json(INPUT)
        assert await _until(lambda: human.status().messages == 1)
        assert human.status().command.override_held

        second = await client.ws_connect("/ws")  # the newest page is the pilot
        await _next_of(second, "hello")
        await first.send_json(INPUT)
        await second.send_json({**INPUT, "buttons": [0] * 8})
        assert await _until(lambda: human.status().messages == 2)
        await asyncio.sleep(0.1)
        assert human.status().messages == 2 and not human.status().command.override_held

        await first.close()  # a watcher leaving changes nothing
        await asyncio.sleep(0.1)
        assert human.status().connected
        await second.close()  # the pilot leaving silences the input at once
        assert await _until(lambda: not human.status().connected)
        assert human.read().hold


def test_the_page_its_socket_and_the_pilot(tmp_path: Path) -> None:
    asyncio.run(_scenario(tmp_path))
