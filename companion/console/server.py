"""The console's web server: the page (static HTML/JS, no build step) and one WebSocket.

Down the socket: JSON messages (``hello`` on connect, ``role`` whenever who flies changes,
``status`` four times a second with the SITL's ground truth, ``step`` every control step,
``episode``, ``notice``, ``error``) and camera frames as binary messages
(:mod:`companion.console.frames`), newest frame first: a slow page skips frames, it never delays
the others. Up the socket: ``role`` (ask for the pilot role, or give it up), ``input`` (the
gamepad's state, at the page's send rate) and ``command`` (:data:`messages.COMMANDS`).

One pilot at a time, explicitly: a page asks for the role and is told it has it; the role moves
only when the pilot gives it up or its socket closes (its input falls silent at once, see
:class:`BrowserInput`, and every page is told). A pilot whose link dropped gets the role back when
the same tab reconnects within :data:`~companion.console.roles.GRACE_S`, unless another page took
it meanwhile (:class:`~companion.console.roles.PilotSeat`). Other pages watch: their input and
commands are refused with an error, never dropped silently. Every message the console does not act on is
logged with its reason (:mod:`companion.console.messages`) and counted to the page (the error
carries the count: at once for the first of a run, then at most every
:data:`~companion.console.messages.REFUSAL_SEND_INTERVAL_S`, never silent); none can close the socket.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import json
import logging
from dataclasses import dataclass, field
from importlib import resources
from typing import Any

from aiohttp import WSMsgType, web

from companion.console import messages
from companion.console.access import LOOPBACK_NAMES, host_ok, origin_ok, page_url, token_ok
from companion.console.messages import RefusalLog, Refused
from companion.console.roles import PilotSeat, tab_key
from companion.console.session import ConsoleSession
from companion.errors import ColError

log = logging.getLogger(__name__)
STATIC = resources.files("companion.console") / "static"
STATIC_FILES = {"index.html": "text/html", "console.js": "text/javascript", "console.css": "text/css"}
STATUS_PERIOD_S = 0.25
MAX_QUEUED = 400  # JSON messages waiting for one page; beyond: the page is dropped
MAX_FRAME_BYTES = 1 << 20  # aiohttp closes a socket over this; our own limit (8 KiB) answers below it
# Ping every 10 s; aiohttp closes a socket whose pong is 5 s late. Finding a dead page is not what
# keeps the vehicle safe (the pilot's input ages out in manual_timeout_s); a ping missed by a busy
# browser or event loop must not cost the pilot the role, so the limit is lenient.
HEARTBEAT_S = 10.0
_FRAME = object()  # marker in a client's queue: send its newest frame


@dataclass(eq=False)
class _Client:
    ws: web.WebSocketResponse
    page: int
    tab: str | None = None  # the tab key the page sent (console/roles.py), if any
    queue: asyncio.Queue[object] = field(default_factory=asyncio.Queue)
    frame: bytes | None = None
    frame_queued: bool = False
    refusals: RefusalLog | None = None
    refusals_due: bool = False  # a call to send the refusals not yet told is scheduled

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
    """Owns the aiohttp application, the connected pages, the pilot role and the session's outlet."""

    def __init__(self, make_session: Any, token: str | None = None,
                 hosts: frozenset[str] = LOOPBACK_NAMES, seat: PilotSeat | None = None) -> None:
        """``make_session(publish, publish_frame)`` builds the :class:`ConsoleSession`;
        ``token``: what every request must carry as ``?token=``; ``hosts``: the names a request's
        ``Host`` may carry (console/access.py); ``seat``: the role kept for a pilot whose link
        dropped (default: :data:`~companion.console.roles.GRACE_S` on the monotonic clock)."""
        self.token, self.hosts = token, hosts
        self.loop: asyncio.AbstractEventLoop | None = None
        self.clients: list[_Client] = []
        self.pilot: _Client | None = None
        self.seat = seat if seat is not None else PilotSeat()
        self._pages = itertools.count(1)
        self._truth: dict[str, Any] | None = None  # the SITL's newest ground truth, for the map
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
            if message.get("type") == "status":  # the session's own status (a run's state changed)
                pilot = self.pilot
                message = {**message, "pilot_page": pilot.page if pilot is not None else None}
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
                log.warning("console page %d does not keep up; closing its socket", client.page)
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
        """The status four times a second, never held up by the SITL: its ground truth (a request
        to the SITL, which a frozen or starved SITL answers late or never) is fetched beside the
        loop, and each status carries the newest truth known by then (None: none yet this run)."""
        fetching: asyncio.Task[None] | None = None
        while True:
            await asyncio.sleep(STATUS_PERIOD_S)
            if not self.clients:
                continue
            running = self.session.running
            if not running:
                self._truth = None
            elif fetching is None or fetching.done():
                fetching = asyncio.create_task(self._fetch_truth())
            status = self.session.status()
            status["truth"] = self._truth if running else None
            status["pilot_page"] = self.pilot.page if self.pilot is not None else None
            self._broadcast(json.dumps(status))

    async def _fetch_truth(self) -> None:
        self._truth = await asyncio.to_thread(self.session.truth)

    # ----- HTTP -------------------------------------------------------------------------------------
    @web.middleware
    async def _guard(self, request: web.Request, handler: Any) -> web.StreamResponse:
        """Every request names this console (no DNS rebinding); the token on the page and the
        socket (the static files hold no secret); on the socket, the page's own origin only."""
        if not host_ok(request.headers.get("Host"), self.hosts):
            log.warning("refused a request for Host %r (not a name this console answers to: a DNS "
                        "rebinding page?)", request.headers.get("Host"))
            raise web.HTTPForbidden(text="this console answers to its own names only "
                                         f"({', '.join(sorted(self.hosts))}); see --allow-host")
        if not request.path.startswith("/static/") and not token_ok(request.query.get("token"), self.token):
            raise web.HTTPForbidden(text="this console needs its token: open it as /?token=...")
        if request.path == "/ws" and not origin_ok(request.headers.getall("Origin", []), request.headers.get("Host")):
            log.warning("refused a WebSocket from another site's page (Origin %s)",
                        ", ".join(request.headers.getall("Origin", [])))
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
        ws = web.WebSocketResponse(heartbeat=HEARTBEAT_S, max_msg_size=MAX_FRAME_BYTES)
        await ws.prepare(request)
        client = _Client(ws, next(self._pages), tab_key(request.query.get("tab")))
        client.refusals = RefusalLog(str(client.page), log)
        self.clients.append(client)
        sender = asyncio.create_task(client.send_loop())
        client.offer_json(json.dumps({**self.session.hello(), "role": self._role_of(client)}))
        self._pilot_returns(client)
        try:
            async for msg in ws:
                if msg.type == WSMsgType.TEXT:
                    self._on_text(client, msg.data)
                elif msg.type == WSMsgType.BINARY:
                    self._refuse(client, "a binary message; the console takes JSON text only")
                elif msg.type == WSMsgType.ERROR:
                    log.warning("console page %d: socket error %r", client.page, ws.exception())
                    break
        finally:
            log.info("console page %d disconnected (close code %s)", client.page, ws.close_code)
            sender.cancel()
            self.clients.remove(client)
            client.refusals.flush()
            if self.pilot is client:
                self._pilot_gone(client, "lost its link")
        return ws

    # ----- the pilot role ----------------------------------------------------------------------
    def _role_of(self, client: _Client) -> dict[str, Any]:
        pilot = self.pilot.page if self.pilot is not None else None
        return {"type": "role", "page": client.page, "role": "pilot" if client is self.pilot else "watch",
                "pilot_page": pilot}

    def _tell_roles(self) -> None:
        for client in self.clients:
            client.offer_json(json.dumps(self._role_of(client)))

    def _take_role(self, client: _Client, want: str) -> None:
        if want == "pilot":
            if self.pilot is not None and self.pilot is not client:
                raise Refused(f"page {self.pilot.page} is the pilot; the role moves only when that page "
                              "gives it up or loses its link")
            if self.pilot is None:
                self.pilot = client
                self.seat.release()
                self.session.human.connected()
                log.info("console page %d is the pilot", client.page)
                self._broadcast(json.dumps({"type": "notice", "text": f"page {client.page} is the pilot"}))
        elif self.pilot is client:
            self._pilot_gone(client, "gave up the pilot role")
            return
        self._tell_roles()

    def _pilot_gone(self, client: _Client, how: str) -> None:
        """The pilot left: its input is silent at once (the vehicle holds if the person was flying);
        a lost link keeps the role for the same tab for a while, giving it up does not."""
        self.pilot = None
        self.session.human.disconnected(f"the pilot's page {client.page} lost its link to the console"
                                        if how == "lost its link" else f"the pilot (page {client.page}) gave up the role")
        kept = how == "lost its link" and self.seat.keep_for(client.tab, client.page)
        text = (f"the pilot's page {client.page} {how}: nobody flies from a page; if the person was "
                "flying, the vehicle holds position")
        if kept:
            text += (f"; the role is kept for that tab for {self.seat.grace_s:g} s "
                     "(any page may still take it)")
        log.warning("%s", text)
        self._broadcast(json.dumps({"type": "notice", "text": text, "pilot_lost": True}))  # in the loop: before the roles
        self._tell_roles()

    def _pilot_returns(self, client: _Client) -> None:
        """A page connected: the pilot again if it is the tab whose link dropped moments ago and
        nobody took the role meanwhile."""
        was = self.seat.returns(client.tab)
        if was is None or self.pilot is not None:
            return
        self.pilot = client
        self.session.human.connected()
        text = f"page {client.page} is the pilot again: its link came back (it was page {was})"
        log.info("%s", text)
        self._broadcast(json.dumps({"type": "notice", "text": text}))
        self._tell_roles()

    # ----- messages from a page ------------------------------------------------------------------
    def _correct_role(self, client: _Client) -> None:
        """A watching page that acted as the pilot is out of step (a stale page, a page edited by
        hand): it is told its role again, so its buttons and banner show what it may do."""
        client.offer_json(json.dumps(self._role_of(client)))

    def _refuse(self, client: _Client, reason: str) -> None:
        """Every refusal is counted and the page told with the count: the first of a run at once,
        the rest at most every REFUSAL_SEND_INTERVAL_S (a broken pad sends 30 messages a second),
        and a count not yet told goes out when that interval ends."""
        refusals = client.refusals
        assert refusals is not None
        if refusals.refused(reason):
            self._tell_refusal(client, reason, refusals.count(reason))
        elif not client.refusals_due and self.loop is not None:
            client.refusals_due = True
            self.loop.call_later(refusals.interval_s, self._tell_unsent, client)

    def _tell_refusal(self, client: _Client, reason: str, count: int) -> None:
        client.offer_json(json.dumps({"type": "error", "message": reason, "count": count}))

    def _tell_unsent(self, client: _Client) -> None:
        client.refusals_due = False
        if client.refusals is not None and client in self.clients:
            for reason, count in client.refusals.unsent():
                self._tell_refusal(client, reason, count)

    def _on_text(self, client: _Client, text: str) -> None:
        try:
            message = messages.parse(text)
            kind = message.get("type")
            if kind == "input":
                try:
                    checked = messages.check_input(message)
                except Refused as exc:
                    if client is self.pilot:  # the hold that follows names it
                        self.session.human.refused(str(exc))
                    raise
                if client is not self.pilot:
                    self._correct_role(client)
                    raise Refused("this page watches: its sticks do not fly (ask for the pilot role)")
                self.session.human.feed(checked)
            elif kind == "command":
                name = messages.command_name(message)
                if client is not self.pilot:
                    self._correct_role(client)
                    raise Refused(f"only the pilot's page can {name.replace('_', ' ')}; this page watches")
                self._command(name, message)
            elif kind == "role":
                self._take_role(client, messages.role_wanted(message))
            else:
                raise Refused(f"unknown message type {str(kind)[:40]!r}; use input, command or role")
            assert client.refusals is not None
            client.refusals.accepted()
        except (ValueError, ColError) as exc:
            self._refuse(client, str(exc))
        except Exception as exc:  # a bug here must not close the pilot's socket
            log.exception("console page %d: a message could not be handled", client.page)
            self._refuse(client, f"the console could not handle that message ({type(exc).__name__}); see its log")

    def _command(self, name: str, message: dict[str, Any]) -> None:
        s = self.session
        if name == "start":
            episodes = messages.whole_number(message.get("episodes"), "episodes", 1, 1000)
            s.start(str(message.get("condition")), episodes, auto=message.get("auto") is True)
        elif name == "go":
            s.go()
        elif name == "auto":
            s.set_auto(message.get("on") is True)
        elif name in ("pause", "resume"):
            s.pause(name == "pause")
        elif name == "next":
            s.next_episode()
        elif name == "stop":
            s.stop()
        elif name == "hand_back":
            s.hand_back()
        elif name == "discard_last":
            s.discard_last(str(message.get("reason") or "discarded by the pilot")[:200])
        elif name == "questionnaire":  # col study: {"answers": {...}} or {"skip": true}
            s.answer_questionnaire(None if message.get("skip") is True else message.get("answers"))


async def _serve(server: ConsoleServer, host: str, port: int, on_ready: Any,
                 autostart: tuple[str, int] | None) -> None:
    runner = web.AppRunner(server.app, handle_signals=False)
    await runner.setup()
    site = web.TCPSite(runner, host, port)
    await site.start()
    bound = runner.addresses  # the ports actually bound (port 0: any free one)
    actual = int(bound[0][1]) if bound else port
    on_ready(page_url(host, actual, server.hosts))
    if autostart is not None:
        server.session.start(*autostart, auto=True)
    try:
        await asyncio.Event().wait()  # until cancelled (Ctrl-C, SIGTERM)
    finally:
        await runner.cleanup()


def run_console(make_session: Any, host: str, port: int, on_ready: Any,
                autostart: tuple[str, int] | None = None, token: str | None = None,
                hosts: frozenset[str] = LOOPBACK_NAMES) -> None:
    """Serve the console until interrupted; ``on_ready(url)`` once it listens."""
    server = ConsoleServer(make_session, token, hosts)
    try:
        asyncio.run(_serve(server, host, port, on_ready, autostart))
    except KeyboardInterrupt:
        pass
    finally:
        server.session.close()
