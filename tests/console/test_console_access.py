"""Who may use the console: another site's page is refused at the socket, a page reached by a
rebound name is refused everywhere, a token guards a console that other machines can reach,
and wider binding must be asked for."""

from __future__ import annotations

import asyncio
from pathlib import Path

import aiohttp
import pytest
from aiohttp.test_utils import TestClient, TestServer
from multidict import CIMultiDict

from companion.config import CompanionConfig
from companion.console.access import (
    LOOPBACK_NAMES,
    allowed_hosts,
    check_console_exposure,
    host_ok,
    origin_ok,
    page_url,
    token_ok,
)
from companion.console.server import ConsoleServer
from companion.console.session import ConsoleOptions, ConsoleSession
from companion.errors import ConfigError

TOKEN = "0123456789abcdef-token"


def _server(tmp_path: Path, token: str | None = None) -> ConsoleServer:
    cfg = CompanionConfig()
    return ConsoleServer(lambda publish, frame: ConsoleSession(cfg, ConsoleOptions(run_dir=tmp_path / "run"),
                                                               publish, frame), token)


def test_origin_must_be_the_consoles_own() -> None:
    assert origin_ok("http://127.0.0.1:8765", "127.0.0.1:8765")
    assert origin_ok(None, "127.0.0.1:8765")  # not a browser: the binding and the token keep it out
    assert not origin_ok("http://evil.example", "127.0.0.1:8765")
    assert not origin_ok("http://127.0.0.1:9999", "127.0.0.1:8765")  # another local page
    assert not origin_ok("null", "127.0.0.1:8765")  # a sandboxed frame or a file:// page
    assert not origin_ok("http://127.0.0.1:8765", None)


@pytest.mark.parametrize("origin", [
    "https://127.0.0.1:8765",  # the console serves plain http: another origin
    "ws://127.0.0.1:8765", "file://127.0.0.1:8765", "http://127.0.0.1:8765/", "http://127.0.0.1:8765/ws",
    "http://user@127.0.0.1:8765", "http://127.0.0.1:87650", "http://127.0.0.1", "http://127.0.0.1:8765 ",
    "http://127.0.0.1:8765, http://evil.example", "", "127.0.0.1:8765",
])
def test_origin_is_exactly_the_consoles_own(origin: str) -> None:
    assert not origin_ok(origin, "127.0.0.1:8765")


def test_an_origin_header_sent_twice_is_refused() -> None:
    own = "http://127.0.0.1:8765"
    assert origin_ok([own], "127.0.0.1:8765") and origin_ok([], "127.0.0.1:8765")
    assert origin_ok("HTTP://LOCALHOST:8765", "localhost:8765") and origin_ok("http://[::1]:8765", "[::1]:8765")
    assert not origin_ok([own, own], "127.0.0.1:8765")
    assert not origin_ok([own, "http://evil.example"], "127.0.0.1:8765")


def test_token_is_compared_only_when_set() -> None:
    assert token_ok(None, None) and token_ok("anything", None)
    assert token_ok(TOKEN, TOKEN)
    assert not token_ok(None, TOKEN) and not token_ok(TOKEN[:-1], TOKEN)


def test_binding_beyond_loopback_must_be_asked_for_with_a_token() -> None:
    check_console_exposure("127.0.0.1", False, None)
    check_console_exposure("localhost", False, None)
    with pytest.raises(ConfigError, match="--allow-remote"):
        check_console_exposure("0.0.0.0", False, None)
    with pytest.raises(ConfigError, match="token of at least"):
        check_console_exposure("0.0.0.0", True, "short")
    check_console_exposure("0.0.0.0", True, TOKEN)


def test_another_sites_page_cannot_open_the_socket(tmp_path: Path) -> None:
    async def scenario() -> None:
        server = _server(tmp_path)
        async with TestServer(server.app, host="127.0.0.1") as ts, TestClient(ts) as client:
            own = f"http://127.0.0.1:{ts.port}"
            ws = await client.ws_connect("/ws", headers={"Origin": own})
            assert (await asyncio.wait_for(ws.receive_json(), 5.0))["type"] == "hello"
            await ws.close()
            with pytest.raises(aiohttp.WSServerHandshakeError) as refused:
                await client.ws_connect("/ws", headers={"Origin": "http://evil.example"})
            assert refused.value.status == 403
            assert server.pilot is None and server.session.human.status().messages == 0

    asyncio.run(scenario())


@pytest.mark.parametrize("origins", [["https://127.0.0.1:{port}"], ["http://127.0.0.1:{port}", "http://127.0.0.1:{port}"],
                                     ["http://127.0.0.1:{port}", "http://evil.example"]])
def test_an_https_or_doubled_origin_cannot_open_the_socket(tmp_path: Path, origins: list[str]) -> None:
    async def scenario() -> None:
        server = _server(tmp_path)
        async with TestServer(server.app, host="127.0.0.1") as ts, TestClient(ts) as client:
            headers = CIMultiDict(("Origin", o.format(port=ts.port)) for o in origins)
            with pytest.raises(aiohttp.WSServerHandshakeError) as refused:
                await client.ws_connect("/ws", headers=headers)
            assert refused.value.status == 403 and not server.clients

    asyncio.run(scenario())


def test_a_token_guards_the_page_and_the_socket_not_the_static_files(tmp_path: Path) -> None:
    async def scenario() -> None:
        server = _server(tmp_path, TOKEN)
        async with TestServer(server.app, host="127.0.0.1") as ts, TestClient(ts) as client:
            assert (await client.get("/")).status == 403
            assert (await client.get("/?token=wrong")).status == 403
            assert (await client.get(f"/?token={TOKEN}")).status == 200
            assert (await client.get("/static/console.js")).status == 200
            with pytest.raises(aiohttp.WSServerHandshakeError):
                await client.ws_connect("/ws")
            ws = await client.ws_connect(f"/ws?token={TOKEN}")
            assert (await asyncio.wait_for(ws.receive_json(), 5.0))["type"] == "hello"
            await ws.close()

    asyncio.run(scenario())


def test_only_the_consoles_own_names_are_answered() -> None:
    assert host_ok("127.0.0.1:8765", LOOPBACK_NAMES) and host_ok("LOCALHOST:8765", LOOPBACK_NAMES)
    assert host_ok("[::1]:8765", LOOPBACK_NAMES) and host_ok("127.0.0.2:8765", LOOPBACK_NAMES)
    for rebound in ("evil.example:8765", "attacker.example", "localhost.evil.example:8765", "127.0.0.1.nip.io:8765"):
        assert not host_ok(rebound, LOOPBACK_NAMES), rebound
    assert not host_ok(None, LOOPBACK_NAMES) and not host_ok("[::1:8765", LOOPBACK_NAMES)
    assert not host_ok("127.0.0.1:http", LOOPBACK_NAMES)
    remote = allowed_hosts("0.0.0.0", True, ("drone-gcs.lan",))
    assert host_ok("drone-gcs.lan:8765", remote) and not host_ok("evil.example:8765", remote)
    assert allowed_hosts("192.168.1.20", False) == LOOPBACK_NAMES  # without --allow-remote: loopback only
    assert "192.168.1.20" in allowed_hosts("192.168.1.20", True)
    assert page_url("0.0.0.0", 8765, remote) == "http://drone-gcs.lan:8765/"  # not http://0.0.0.0:...
    assert page_url("127.0.0.1", 8765, LOOPBACK_NAMES) == "http://127.0.0.1:8765/"


def test_a_rebinding_host_is_refused_even_with_a_matching_origin(tmp_path: Path) -> None:
    async def scenario() -> None:
        server = _server(tmp_path)
        async with TestServer(server.app, host="127.0.0.1") as ts, TestClient(ts) as client:
            evil = f"evil.example:{ts.port}"
            assert (await client.get("/", headers={"Host": evil})).status == 403
            assert (await client.get("/static/console.js", headers={"Host": evil})).status == 403
            with pytest.raises(aiohttp.WSServerHandshakeError) as refused:
                await client.ws_connect("/ws", headers={"Host": evil, "Origin": f"http://{evil}"})
            assert refused.value.status == 403
            assert not server.clients and server.session.human.status().messages == 0
            assert (await client.get("/", headers={"Host": f"localhost:{ts.port}"})).status == 200

    asyncio.run(scenario())
