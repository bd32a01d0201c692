"""The console's web server: the page (static HTML/JS, no build step) and one WebSocket.

Down the socket: JSON messages (``hello`` on connect, ``status`` four times a second with the
SITL's ground truth, ``step`` every control step, ``episode``, ``notice``, ``error``) and camera
frames as binary messages (:mod:`companion.console.frames`), newest frame first: a slow page
skips frames, it never delays the others. Up the socket: ``input`` (the gamepad's state, at
the page's send rate) and ``command`` (start, pause, resume, next, stop, hand_back).

The most recent page to connect is the pilot; others only watch (their input is ignored).
When the pilot's socket closes, its input falls silent at once (see :class:`BrowserInput`).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
from dataclasses import dataclass, field
from importlib import resources
from typing import Any

from aiohttp import WSMsgType, web

from companion.console.access import origin_ok, token_ok
from companion.console.session import ConsoleSession
from companion.errors import ColError

log = logging.getLogger(__name__)
STATIC = resources.files("companion.console") / "static"
STATIC_FILES = {"index.html": "text/html", "console.js": "text/javascript", "console.css": "text/css"}
STATUS_PERIOD_S = 0.25
MAX_QUEUED = 400  # JSON messages waiting for one page; beyond: the page is dropped
_FRAME = object()  # marker in a client's queue: send its newest frame


@dataclass(eq=False)
class _Client:
    ws: web.WebSocketResponse
    queue: asyncio.Queue[object] = field(default_factory=asyncio.Queue)
    frame: bytes | None = None
    frame_queued: bool = False

    def offer_json(self, text: str) -> bool:
        if self.queue.qsize() >= MAX_QUEUED:
            return False
        self.queue.put_nowait(text)
        return True

    def offer_frame(self, data: bytes) -> None:
        self.frame = data
        if not self.frame_queued:
            self.frame_queued = True
            self.queue.put_nowait(_FRAME)

    async def send_loop(self) -> None:
        while True:
            item = await self.queue.get()
            if item is _FRAME:
                self.frame_queued = False
                data, self.frame = self.frame, None
                if data is not None:
                    await self.ws.send_bytes(data)
            else:
                await self.ws.send_str(str(item))


class ConsoleServer:
    """Owns the aiohttp application, the connected pages and the session's outlet to them."""

    def __init__(self, make_session: Any, token: str | None = None) -> None:
        """``make_session(publish, publish_frame)`` builds the :class:`ConsoleSession`;
        ``token``: what every request must carry as ``?token=`` (console/access.py)."""
        self.token = token
        self.loop: asyncio.AbstractEventLoop | None = None
        self.clients: list[_Client] = []
        self.pilot: _Client | None = None
        self.session: ConsoleSession = make_session(self.publish, self.publish_frame)
        self.app = web.Application(middlewares=[self._guard])
        self.app.router.add_get("/", self._index)
        self.app.router.add_get("/static/{name}", self._static)
        self.app.router.add_get("/ws", self._ws)
        self.app.on_startup.append(self._on_startup)
        self.app.on_shutdown.append(self._on_shutdown)

    # ----- thread-safe outlets for the session --------------------------------------------------
    def publish(self, message: dict[str, Any]) -> None:
        if self.loop is not None and not self.loop.is_closed():
            text = json.dumps(message)
            with contextlib.suppress(RuntimeError):  # the loop closed meanwhile
                self.loop.call_soon_threadsafe(self._broadcast, text)

    def publish_frame(self, data: bytes) -> None:
        if self.loop is not None and not self.loop.is_closed():
            with contextlib.suppress(RuntimeError):
                self.loop.call_soon_threadsafe(self._broadcast_frame, data)

    def _broadcast(self, text: str) -> None:
        for client in list(self.clients):
            if not client.offer_json(text):
                log.warning("a console page does not keep up; closing its socket")
                asyncio.ensure_future(client.ws.close())

    def _broadcast_frame(self, data: bytes) -> None:
        for client in self.clients:
            client.offer_frame(data)

    # ----- lifecycle ------------------------------------------------------------------------------
    async def _on_startup(self, app: web.Application) -> None:
        self.loop = asyncio.get_running_loop()
        self._status_task = asyncio.create_task(self._status_loop())

    async def _on_shutdown(self, app: web.Application) -> None:
        self._status_task.cancel()
        for client in list(self.clients):
            await client.ws.close()
        await asyncio.to_thread(self.session.close)

    async def _status_loop(self) -> None:
        while True:
            await asyncio.sleep(STATUS_PERIOD_S)
            if not self.clients:
                continue
            status = self.session.status()
            status["truth"] = await asyncio.to_thread(self.session.truth) if self.session.running else None
            self._broadcast(json.dumps(status))

    # ----- HTTP -------------------------------------------------------------------------------------
    @web.middleware
    async def _guard(self, request: web.Request, handler: Any) -> web.StreamResponse:
        """The token on the page and the socket (the static files hold no secret); on the
        socket, the page's own origin only."""
        if not request.path.startswith("/static/") and not token_ok(request.query.get("token"), self.token):
            raise web.HTTPForbidden(text="this console needs its token: open it as /?token=...")
        if request.path == "/ws" and not origin_ok(request.headers.get("Origin"), request.headers.get("Host")):
            log.warning("refused a WebSocket from another site's page (Origin %s)", request.headers.get("Origin"))
            raise web.HTTPForbidden(text="the console's socket accepts its own page only")
        return await handler(request)

    async def _index(self, request: web.Request) -> web.Response:
        return web.Response(text=(STATIC / "index.html").read_text(), content_type="text/html")

    async def _static(self, request: web.Request) -> web.Response:
        name = request.match_info["name"]
        if name not in STATIC_FILES:
            raise web.HTTPNotFound(text=f"no static file {name!r}")
        return web.Response(text=(STATIC / name).read_text(), content_type=STATIC_FILES[name])

    async def _ws(self, request: web.Request) -> web.WebSocketResponse:
        ws = web.WebSocketResponse(heartbeat=5.0, max_msg_size=1 << 16)
        await ws.prepare(request)
        client = _Client(ws)
        self.clients.append(client)
        self.pilot = client
        self.session.human.connected()
        sender = asyncio.create_task(client.send_loop())
        client.offer_json(json.dumps(self.session.hello()))
        try:
            async for msg in ws:
                if msg.type == WSMsgType.TEXT:
                    self._on_text(client, msg.data)
                elif msg.type == WSMsgType.ERROR:
                    break
        finally:
            sender.cancel()
            self.clients.remove(client)
            if self.pilot is client:
                self.pilot = None
                self.session.human.disconnected()
                log.warning("the pilot's console page disconnected")
                self.publish({"type": "notice", "text": "the pilot's page disconnected"})
        return ws

    def _on_text(self, client: _Client, text: str) -> None:
        try:
            message = json.loads(text)
            if not isinstance(message, dict):
                raise ValueError("a message is a JSON object")
            kind = message.get("type")
            if kind == "input":
                if client is self.pilot:
                    self.session.human.feed(message)
            elif kind == "command":
                self._command(message)
            else:
                raise ValueError(f"unknown message type {kind!r}")
        except (ValueError, ColError) as exc:
            client.offer_json(json.dumps({"type": "error", "message": str(exc)}))

    def _command(self, message: dict[str, Any]) -> None:
        name = message.get("name")
        s = self.session
        if name == "start":
            s.start(str(message.get("condition")), message.get("episodes"))  # type: ignore[arg-type]
        elif name in ("pause", "resume"):
            s.pause(name == "pause")
        elif name == "next":
            s.next_episode()
        elif name == "stop":
            s.stop()
        elif name == "hand_back":
            s.hand_back()
        else:
            raise ValueError(f"unknown command {name!r}; use start, pause, resume, next, stop or hand_back")


async def _serve(server: ConsoleServer, host: str, port: int, on_ready: Any,
                 autostart: tuple[str, int] | None) -> None:
    runner = web.AppRunner(server.app, handle_signals=False)
    await runner.setup()
    site = web.TCPSite(runner, host, port)
    await site.start()
    bound = runner.addresses  # the ports actually bound (port 0: any free one)
    actual = int(bound[0][1]) if bound else port
    on_ready(f"http://{host}:{actual}/")
    if autostart is not None:
        server.session.start(*autostart)
    try:
        await asyncio.Event().wait()  # until cancelled (Ctrl-C, SIGTERM)
    finally:
        await runner.cleanup()


def run_console(make_session: Any, host: str, port: int, on_ready: Any,
                autostart: tuple[str, int] | None = None, token: str | None = None) -> None:
    """Serve the console until interrupted; ``on_ready(url)`` once it listens."""
    server = ConsoleServer(make_session, token)
    try:
        asyncio.run(_serve(server, host, port, on_ready, autostart))
    except KeyboardInterrupt:
        pass
    finally:
        server.session.close()
