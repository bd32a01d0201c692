"""The pilot's seat: a pilot whose link dropped gets the role back when the same tab returns in
time, never locks another page out, and a page without a (well-formed) tab key gets no seat."""

from __future__ import annotations

import asyncio
from pathlib import Path

import pytest
from aiohttp.test_utils import TestClient, TestServer

from companion.config import CompanionConfig
from companion.console.roles import PilotSeat, tab_key
from companion.console.server import ConsoleServer
from companion.console.session import ConsoleOptions, ConsoleSession
from tests.console.test_console_server import INPUT, PILOT, _next_of, _until

TAB = "0123456789abcdef0123456789abcdef"
OTHER = "fedcba9876543210fedcba9876543210"


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_the_seat_is_kept_for_the_same_tab_until_the_grace_runs_out() -> None:
    clock = Clock()
    seat = PilotSeat(15.0, clock)
    assert seat.keep_for(TAB, 3) and seat.kept_for == 3
    assert seat.returns(OTHER) is None and seat.kept_for == 3  # another tab does not use it up
    clock.now += 15.0
    assert seat.returns(TAB) == 3  # just in time
    assert seat.returns(TAB) is None and seat.kept_for is None  # used up

    seat.keep_for(TAB, 4)
    clock.now += 15.01
    assert seat.kept_for is None and seat.returns(TAB) is None  # too late

    seat.keep_for(TAB, 5)
    seat.release()  # another page took the role
    assert seat.returns(TAB) is None
    assert not seat.keep_for(None, 6) and seat.returns(None) is None  # no key, no seat
    assert not PilotSeat(0.0, clock).keep_for(TAB, 7)  # grace 0: the old behaviour
    with pytest.raises(ValueError, match="grace"):
        PilotSeat(float("nan"))


@pytest.mark.parametrize("raw,ok", [(TAB, True), ("ABCDEF0123456789", False), ("abc", False), ("", False), (None, False),
                                    ("0123456789abcdef" * 5, False), ("0123456789abcdeg", False),
                                    ("0123456789abcdef\n", False)])
def test_tab_keys_are_checked(raw: str | None, ok: bool) -> None:
    assert tab_key(raw) == (raw if ok else None)


def _server(tmp_path: Path, clock: Clock) -> ConsoleServer:
    cfg = CompanionConfig()
    return ConsoleServer(lambda publish, frame: ConsoleSession(cfg, ConsoleOptions(run_dir=tmp_path / "run"), publish, frame),
                         seat=PilotSeat(15.0, clock))


async def _pilot(client: TestClient, tab: str | None):  # type: ignore[no-untyped-def]
    ws = await client.ws_connect("/ws" + (f"?tab={tab}" if tab else ""))
    await _next_of(ws, "hello")
    await ws.send_json(PILOT)
    assert (await _next_of(ws, "role"))["role"] == "pilot"
    return ws


async def _returns_in_time(tmp_path: Path) -> None:
    clock = Clock()
    server = _server(tmp_path, clock)
    human = server.session.human
    async with TestServer(server.app, host="127.0.0.1") as ts, TestClient(ts) as client:
        first = await _pilot(client, TAB)
        watcher = await client.ws_connect(f"/ws?tab={OTHER}")
        await _next_of(watcher, "hello")
        await first.close()  # the link drops
        notice = await _next_of(watcher, "notice")
        assert notice["pilot_lost"] and "kept for that tab for 15 s" in notice["text"]
        assert await _until(lambda: not human.status().connected) and human.read().hold

        clock.now += 14.0
        again = await client.ws_connect(f"/ws?tab={TAB}")  # the same tab, in time
        hello = await _next_of(again, "hello")
        assert hello["role"]["role"] == "watch"  # told at once after the hello:
        role = await _next_of(again, "role")
        assert role["role"] == "pilot" and role["pilot_page"] == role["page"] == hello["role"]["page"]
        assert "pilot again" in (await _next_of(watcher, "notice"))["text"]
        await again.send_json(INPUT)  # its sticks fly again
        assert await _until(lambda: human.status().messages == 1)
        assert human.status().connected and human.status().command.override_held
        await watcher.send_json(PILOT)
        assert "is the pilot" in (await _next_of(watcher, "error"))["message"]
        for ws in (again, watcher):
            await ws.close()


def test_the_pilots_tab_gets_the_role_back_when_its_link_returns_in_time(tmp_path: Path) -> None:
    asyncio.run(_returns_in_time(tmp_path))


async def _not_kept(tmp_path: Path) -> None:
    clock = Clock()
    server = _server(tmp_path, clock)
    async with TestServer(server.app, host="127.0.0.1") as ts, TestClient(ts) as client:
        # another page may take the role while the seat is kept: the seat is then gone
        first = await _pilot(client, TAB)
        await first.close()
        assert await _until(lambda: server.pilot is None)
        other = await _pilot(client, OTHER)
        back = await client.ws_connect(f"/ws?tab={TAB}")
        assert (await _next_of(back, "hello"))["role"]["role"] == "watch"
        await back.send_json(PILOT)
        assert "is the pilot" in (await _next_of(back, "error"))["message"]
        assert server.pilot is not None and server.pilot.tab == OTHER
        await other.send_json({"type": "role", "want": "watch"})  # giving it up keeps no seat
        assert await _until(lambda: server.pilot is None)
        assert server.seat.kept_for is None
        await back.close()
        await other.close()

        # too late: the returning tab watches, and may ask
        first = await _pilot(client, TAB)
        await first.close()
        assert await _until(lambda: server.pilot is None)
        clock.now += 15.5
        late = await client.ws_connect(f"/ws?tab={TAB}")
        await _next_of(late, "hello")
        await late.send_json(INPUT)
        assert "watches" in (await _next_of(late, "error"))["message"] and server.pilot is None
        await late.close()


def test_the_seat_never_locks_another_page_out_and_runs_out(tmp_path: Path) -> None:
    asyncio.run(_not_kept(tmp_path))
