"""The console's server without a vehicle: the page and its files, the WebSocket's messages,
refused requests (each logged, none closing the socket), and the one pilot role."""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import pytest
from aiohttp import WSMsgType
from aiohttp.test_utils import TestClient, TestServer

from companion.config import CompanionConfig
from companion.console.server import ConsoleServer
from companion.console.session import ConsoleOptions, ConsoleSession

INPUT = {"type": "input", "axes": [0, 0, 0, -0.5], "buttons": [0] * 7 + [1], "seq": 0, "t": 0}
PILOT = {"type": "role", "want": "pilot"}


def make_server(tmp_path: Path) -> ConsoleServer:
    cfg = CompanionConfig()
    return ConsoleServer(lambda publish, frame: ConsoleSession(cfg, ConsoleOptions(run_dir=tmp_path / "run"), publish, frame))


async def _until(test, timeout_s: float = 10.0) -> bool:  # type: ignore[no-untyped-def]
    for _ in range(int(timeout_s / 0.01)):
        if test():
            return True
        await asyncio.sleep(0.01)
    return bool(test())


async def _next_of(ws, kind: str, timeout_s: float = 20.0) -> dict:  # type: ignore[no-untyped-def]
    async def find() -> dict:
        while True:
            message = await ws.receive_json()
            if message["type"] == kind:
                return message

    return await asyncio.wait_for(find(), timeout_s)


@contextlib.asynccontextmanager
async def _client(server: ConsoleServer) -> AsyncIterator[TestClient]:
    """A client of ``server``, served on a free loopback port for the block."""
    async with TestServer(server.app, host="127.0.0.1") as ts, TestClient(ts) as client:
        yield client


async def _take_pilot(ws) -> dict:  # type: ignore[no-untyped-def]
    """Ask for the pilot role on the socket ``ws``: the role message that answers."""
    await ws.send_json(PILOT)
    return await _next_of(ws, "role")


@contextlib.asynccontextmanager
async def _pilot_socket(server: ConsoleServer) -> AsyncIterator[tuple[Any, dict]]:
    """A page's socket to ``server`` that has taken the pilot role, and the role message."""
    async with _client(server) as client:
        ws = await client.ws_connect("/ws")
        yield ws, await _take_pilot(ws)


async def _files(client: TestClient) -> None:
    page = await client.get("/")
    assert page.status == 200 and "pilot console" in await page.text()
    for name in ("console.js", "console.css", "index.html"):
        assert (await client.get(f"/static/{name}")).status == 200
    assert (await client.get("/static/secret.py")).status == 404


async def _scenario(tmp_path: Path) -> None:
    server = make_server(tmp_path)
    human = server.session.human
    async with _client(server) as client:
        await _files(client)
        first = await client.ws_connect("/ws")
        hello = await _next_of(first, "hello")
        assert hello["conditions"] == ["demo", "int", "col", "colplus"] and hello["control_rate_hz"] == 10.5
        assert hello["status"]["run"]["state"] == "idle" and hello["records"] == []
        assert hello["role"]["role"] == "watch" and hello["role"]["pilot_page"] is None

        await first.send_json(INPUT)  # a watcher's sticks are refused, not dropped silently
        assert "watches" in (await _next_of(first, "error"))["message"]
        await first.send_json({"type": "command", "name": "start", "condition": "col", "episodes": 1})
        assert "only the pilot" in (await _next_of(first, "error"))["message"]
        assert human.status().messages == 0 and not server.session.running

        role = await _take_pilot(first)
        assert role["role"] == "pilot" and role["pilot_page"] == role["page"]
        for bad, why in [({"type": "command", "name": "start", "condition": "eval", "episodes": 1}, "condition"),
                         ({"type": "command", "name": "start", "condition": "col", "episodes": 0}, "episodes"),
                         ({"type": "command", "name": "start", "condition": "col", "episodes": 2.5}, "whole number"),
                         ({"type": "command", "name": "stop"}, "no run"),
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

        second = await client.ws_connect("/ws")  # a second tab: it watches, the pilot stays
        assert (await _next_of(second, "hello"))["role"]["role"] == "watch"
        await second.send_json(PILOT)
        assert "is the pilot" in (await _next_of(second, "error"))["message"]
        await second.send_json({**INPUT, "buttons": [0] * 8})
        corrected = await _next_of(second, "role")  # a watcher that acts as the pilot is told its role again
        assert corrected["role"] == "watch" and corrected["pilot_page"] == role["page"]
        await first.send_json(INPUT)
        assert await _until(lambda: human.status().messages == 2)
        assert human.status().command.override_held  # the pilot's override is not dropped

        await second.close()  # a watcher leaving changes nothing
        await first.send_json(INPUT)
        assert await _until(lambda: human.status().messages == 3)
        assert human.status().connected and server.pilot is not None

        third = await client.ws_connect("/ws")
        await _next_of(third, "hello")
        await first.close()  # the pilot leaving: its input is silent at once, every page is told
        assert await _until(lambda: not human.status().connected)
        assert human.read().hold
        notice = await _next_of(third, "notice")
        assert notice.get("pilot_lost") and "holds position" in notice["text"]
        assert (await _next_of(third, "role"))["pilot_page"] is None
        assert (await _take_pilot(third))["role"] == "pilot"  # now another page may take the role
        await third.send_json({"type": "role", "want": "watch"})  # and give it up
        assert (await _next_of(third, "role"))["role"] == "watch" and server.pilot is None
        await third.close()


def test_the_page_its_socket_and_the_one_pilot(tmp_path: Path) -> None:
    asyncio.run(_scenario(tmp_path))


@pytest.mark.parametrize("text,why", [("[" * 60_000, "at most"), ("[" * 5000, "nested too deeply"), ("{" * 5000, "not JSON"),
                                      ("x" * 9000, "at most"), ('{"type": "input", "axes": [NaN], "buttons": []}', "outside"),
                                      ('{"type": "input", "axes": [null, 0, 0, 0], "buttons": []}', "NaN or Infinity"),
                                      ('{"type": "input", "axes": [1e308], "buttons": []}', "outside"),
                                      ('{"type": "input", "axes": [0, 0, 0, 5], "buttons": []}', "outside"),
                                      ('{"type": "input", "axes": [0], "buttons": [-Infinity]}', "outside"),
                                      ('{"type": "input", "axes": [true], "buttons": []}', "not a number")])
def test_malformed_messages_are_logged_refused_and_keep_the_socket(tmp_path: Path, text: str, why: str,
                                                                  caplog: pytest.LogCaptureFixture) -> None:
    async def scenario() -> None:
        server = make_server(tmp_path)
        async with _pilot_socket(server) as (ws, _):
            await ws.send_str(text)
            assert why in (await _next_of(ws, "error"))["message"]
            await ws.send_bytes(b"\x00\x01")
            assert "binary" in (await _next_of(ws, "error"))["message"]
            await ws.send_json(INPUT)  # the socket lives on and good input still flies
            assert await _until(lambda: server.session.human.status().messages == 1)
            assert server.pilot is not None and not ws.closed
            await ws.close()
            assert ws.close_code != 1009 and (await ws.receive()).type in (WSMsgType.CLOSED, WSMsgType.CLOSE)

    with caplog.at_level(logging.WARNING, logger="companion.console.server"):
        asyncio.run(scenario())
    assert any(why in r.getMessage() and "refused" in r.getMessage() for r in caplog.records)


async def _errors(ws, count: int, timeout_s: float = 20.0) -> list[dict]:  # type: ignore[no-untyped-def]
    """Error messages until one carries ``count`` (the server's running count of that reason)."""
    seen: list[dict] = []
    while not seen or seen[-1].get("count") != count:
        seen.append(await _next_of(ws, "error", timeout_s))
    return seen


def test_a_pad_that_is_not_a_pad_is_refused_and_every_refusal_is_counted(tmp_path: Path) -> None:
    async def scenario() -> None:
        server = make_server(tmp_path)
        human = server.session.human
        async with _pilot_socket(server) as (ws, _):
            two_axes = {**INPUT, "axes": [0, -0.5]}  # a pad with one stick, trigger held
            await ws.send_json(two_axes)
            first = await _next_of(ws, "error")
            assert first["message"].startswith("this gamepad reports 2 axes") and first["count"] == 1
            for _ in range(4):  # a broken pad sends 30 a second: counted, told with the count
                await ws.send_json(two_axes)
            assert (await _errors(ws, 5))[-1]["message"] == first["message"]
            assert human.status().messages == 0  # nothing of it reached the session: no centred sticks

            await ws.send_json({**INPUT, "buttons": [1.0] * 7})  # no trigger: refused, not "released"
            assert "reports 7 buttons" in (await _next_of(ws, "error"))["message"]
            await ws.send_json(INPUT)  # good input
            assert await _until(lambda: human.status().messages == 1)
            await ws.send_json(two_axes)  # the same fault again: told again, counted on
            assert (await _errors(ws, 6))[-1]["message"] == first["message"]
            # the good input ages out: the input's status says it is refused, and why (not "lost its link")
            assert await _until(lambda: "refused (this gamepad reports 2 axes" in (human.status().lost_reason or ""))
            assert human.read().hold and "refused (this gamepad" in (human.status().hold_reason or "")
            await ws.close()

    asyncio.run(scenario())


def test_the_inputs_status_names_how_the_pilot_left(tmp_path: Path) -> None:
    async def scenario() -> None:
        server = make_server(tmp_path)
        human = server.session.human
        async with _pilot_socket(server) as (ws, role):
            page = role["page"]
            await ws.send_json(INPUT)  # the trigger held
            assert await _until(lambda: human.status().messages == 1)
            await ws.send_json({"type": "role", "want": "watch"})  # the pilot gives the role up
            assert (await _next_of(ws, "role"))["role"] == "watch"
            assert human.status().lost_reason == f"the pilot (page {page}) gave up the role"
            assert human.read().hold
            assert human.status().hold_reason == f"the pilot (page {page}) gave up the role while the person held the override"
            assert server.session.status()["input"]["hold_reason"] == human.status().hold_reason

            await _take_pilot(ws)  # back, and then its link drops
            await ws.send_json(INPUT)
            assert await _until(lambda: human.status().messages == 2)
            await ws.close()
            assert await _until(lambda: human.status().lost_reason == f"the pilot's page {page} lost its link to the console")

    asyncio.run(scenario())
