"""Evaluation runs against a lockstep SITL in the companion's own process and thread.

Why: an evaluation run is the policy alone on a seeded start, thousands of them per grid. Over
sockets each control step costs two processes, UDP datagrams, a camera frame over TCP and the
thread hand-overs around them (about 3 ms of CPU per step); in one thread the same step costs
about half. Why it is the same experiment: the same code runs on both sides as over MAVLink -
the SITL's :class:`~sitl.server.SitlServer` frame loop, ``MessageHandler`` and control surface,
the companion's :class:`~companion.link.mavlink_link.MavlinkLink` (commands, ACK waits,
telemetry folding), observer, detector and episode loop. Only the transport is replaced:

- MAVLink messages are handed over as the receiving parser would make them
  (:func:`~companion.link.wire_copy.wire_copy`: the same payload packing and unpacking, so every
  float is rounded to float32 exactly as on the wire, but no framing, checksums or byte-wise
  parsing); with MAVLink signing on, the signed bytes themselves travel and are parsed;
- camera frames are handed over as the rendered image (a raw frame on the stream is lossless,
  so these are the pixels the stream would carry; a JPEG stream's frames are encoded and
  decoded as on the stream);
- control-surface requests are JSON lines answered by :meth:`SitlServer.control_reply`.

A frame is computed when the companion waits for the next one, after it answered the current
one: what strict lockstep does with a client that always answers in time. Disturbances
(``[sitl.disturbance]``: wind, pixel noise, camera latency, ...) live in the SITL's vehicle,
renderer and server, and run here unchanged. ``tests/experiment/test_inprocess.py`` checks
that evaluation over MAVLink and in-process give the same records and touchdown points.

:func:`inprocess_vehicle` is a :data:`companion.app.VehicleOpener`: ``run_episodes(cfg, opts,
vehicle=inprocess_vehicle)`` flies the in-process SITL built from ``opts.config_path``.
"""

from __future__ import annotations

import contextlib
import json
import math
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from colcommon.frames import Frame, decode_frame, encode_frame
from companion.app import RunOptions, Vehicle
from companion.config import CompanionConfig, LinkConfig
from companion.errors import ConfigError, SimulatorError
from companion.link.connection import parse_connection
from companion.link.mavlink_io import MavlinkIO, SnapshotTest
from companion.link.mavlink_link import MavlinkLink
from companion.link.wire_copy import wire_copy
from companion.msg.snapshot import VehicleSnapshot
from companion.shared_facts import check_shared_facts
from companion.simulator import SimulatorClient
from sitl.config import SitlConfig, load_sitl_config
from sitl.handler import Outgoing
from sitl.server import SitlServer
from sitl.transports import MavClient

INPROCESS_CONNECTION = "udpin:127.0.0.1:1"
"""What the link's config names as its connection (messages only; no port is opened)."""
CAMERA_URI = "inprocess://camera"


# ====================================================================== the SITL's side
class _Handoff(bytes):
    """A message handed over without the wire: to the server's sending code, which passes it on
    unread, empty bytes; to the in-process peer, ``message`` as the companion's parser makes it."""

    message: Any


class _CompanionPeer(MavClient):
    """The SITL's view of the companion: what the SITL sends it is queued, bytes or messages
    (:class:`_Handoff`), in order."""

    name = "inprocess"

    def __init__(self) -> None:
        super().__init__()
        self.active = True  # talks from the start: no greeting HEARTBEATs for a silent peer
        self._outbox: list[Any] = []

    def send(self, data: bytes) -> None:
        self._outbox.append(data.message if isinstance(data, _Handoff) else bytes(data))

    def take(self) -> list[Any]:
        """Everything sent since the last call, in order: bytes, or messages as parsed."""
        items, self._outbox = self._outbox, []
        return items

    def close(self) -> None:
        self._outbox = []


class _FrameSlot:
    """The camera's frame sink: keeps the newest frame as the stream would deliver it."""

    uri = CAMERA_URI
    port = 0
    client_count = 1  # the companion's camera is always connected (over sockets it connects first)

    def __init__(self, encoding: str, jpeg_quality: int) -> None:
        self.encoding, self.jpeg_quality = encoding, jpeg_quality
        self.latest: Frame | None = None

    def publish(self, frame: Frame, blocking: bool) -> None:
        if self.encoding == "raw":  # the stream copies the pixels; so do we, never sharing a buffer
            self.latest = Frame(frame.frame_number, frame.time_boot_ms, frame.image.copy())
        else:  # lossy: exactly the pixels a reader of the stream decodes
            self.latest = decode_frame(encode_frame(frame, self.encoding, self.jpeg_quality))

    def close(self) -> None:
        self.latest = None


class InProcessSitl(SitlServer):
    """A lockstep :class:`SitlServer` with one in-process client, stepped on demand.

    No MAVLink sockets and no camera stream; the frame loop, the message handler and the control
    surface are the server's own. Strict lockstep from the first frame (over sockets the frames
    before the first episode reset are paced in real time; the reset restarts everything an
    episode uses, so episodes do not depend on them).
    """

    def __init__(self, cfg: SitlConfig) -> None:
        cfg = inprocess_config(cfg)
        self.frames = _FrameSlot(cfg.camera.encoding, cfg.camera.jpeg_quality)
        super().__init__(cfg, frame_sink=self.frames)
        self.peer = _CompanionPeer()
        self.clients.append(self.peer)
        self.stats.attached = True
        self.frame_rate_hz = cfg.clock.frame_rate_hz

    def _await_answer(self) -> None:
        """Nothing to wait for: the companion's answer arrives (through :meth:`receive`) before
        it asks for the next frame (:meth:`advance`)."""
        self._at_frame_boundary = True

    def advance(self) -> None:
        """Run the next frame; the current one counts as answered or as timed out, as over sockets."""
        if self.stats.frames:
            if self._answered:
                self.stats.answered += 1
            else:
                self.stats.timeouts += 1
        self._run_frame()

    def receive(self, data: bytes) -> None:
        """MAVLink bytes from the companion, handled between frames as the socket SITL does."""
        self._on_mavlink(self.peer, self.peer.parse(data))

    def receive_message(self, msg: Any) -> None:
        """One message from the companion, as this SITL's parser would have made it."""
        self._on_mavlink(self.peer, [msg])

    @property
    def needs_wire(self) -> bool:
        """Whether messages must travel as bytes: signatures cover the framed bytes."""
        return self.signing.required or any(m.signing.sign_outgoing for m in self._mav_out.values())

    def _pack(self, out: Outgoing) -> bytes:
        if self.needs_wire:
            return super()._pack(out)
        handoff = _Handoff()
        handoff.message = wire_copy(out.message, self._mav_out[out.component])
        return handoff

    def request(self, request: dict[str, Any]) -> dict[str, Any]:
        """One control-surface request, as the JSON line a socket client sends; the reply as
        that client reads it back."""
        reply = self.control_reply((json.dumps(request) + "\n").encode())
        self._flush_events()
        self._flush_all()
        return dict(json.loads(json.dumps(reply)))

    @property
    def latest_frame(self) -> Frame | None:
        return self.frames.latest


def inprocess_config(cfg: SitlConfig) -> SitlConfig:
    """``cfg`` in lockstep, without MAVLink ports (the control listener binds a free loopback
    port that nobody uses)."""
    data = cfg.model_dump()
    data["clock"]["mode"] = "lockstep"
    data["network"].update(udp_local_ports=(), udp_remote_ports=(), tcp_port=None, camera_port=0, control_port=0)
    return SitlConfig.model_validate(data)


# ====================================================================== the companion's side
def _codec(file: Any, cfg: LinkConfig) -> Any:
    """A MAVLink 2 codec as :func:`~companion.link.connection.open_mavlink` gives a connection
    (same dialect, same ids, robust parsing); it writes what it sends to ``file``."""
    from pymavlink.dialects.v20 import ardupilotmega as dialect

    mav = dialect.MAVLink(file, srcSystem=cfg.source_system, srcComponent=cfg.source_component)
    mav.robust_parsing = True
    return mav


class _LoopConnection:
    """What :class:`MavlinkIO` uses of a pymavlink connection: ``mav``, whose writes reach the
    SITL, and ``close``."""

    def __init__(self, sitl: InProcessSitl, cfg: LinkConfig) -> None:
        self._sitl = sitl
        self.mav = _codec(self, cfg)

    def write(self, buf: bytes) -> None:
        self._sitl.receive(bytes(buf))

    def close(self) -> None:
        pass


class InProcessIO(MavlinkIO):
    """:class:`MavlinkIO` without its thread: the SITL's bytes are parsed and folded where
    they appear (after each send, and after each frame the companion waits for)."""

    def __init__(self, cfg: LinkConfig, sitl: InProcessSitl, clock: Callable[[], float] = time.monotonic) -> None:
        super().__init__(cfg, parse_connection(INPROCESS_CONNECTION), None, clock)
        self._sitl = sitl
        self._parser = _codec(None, cfg)

    def start(self) -> None:
        if self.closed:
            super().start()  # raises LinkLost, as for a closed socket link
        if self._conn is None:
            self._conn = _LoopConnection(self._sitl, self.cfg)

    def send(self, msg: Any) -> None:
        conn = self._conn
        if conn is None or self._tlog is not None or conn.mav.signing.sign_outgoing or self._sitl.needs_wire:
            super().send(msg)  # the bytes themselves: signed, or logged
        else:
            with self._send_lock:
                self._sitl.receive_message(wire_copy(msg, conn.mav))
        self.drain()  # the SITL answered at once (COMMAND_ACK, PARAM_VALUE): fold it now

    def drain(self) -> None:
        """Handle what the SITL has sent, in order, as the I/O thread would."""
        for item in self._sitl.peer.take():
            if isinstance(item, bytes):
                for msg in self._parser.parse_buffer(item) or []:
                    self._handle(msg)
            else:
                self._handle(item)

    def wait(self, ready: SnapshotTest, timeout_s: float,
             on_loss: Callable[[], None] | None = None) -> VehicleSnapshot | None:
        """Run frames until ``ready`` holds; ``timeout_s`` counts simulated time (a frame is
        never late in one thread). None after that many frames, or when closed."""
        self.drain()
        for _ in range(max(1, math.ceil(timeout_s * self._sitl.frame_rate_hz))):
            if ready(self.snapshot):
                return self.snapshot
            if self.closed:
                return None
            self._sitl.advance()
            self.drain()
        return self.snapshot if ready(self.snapshot) else None

    def alive(self) -> bool:
        """Heard once and not closed. The vehicle speaks only when the companion advances it, so
        its silence while the companion thinks (a loaded machine, a slow first step) is not a
        lost link: a wall-clock silence had ended an in-process episode as ``link_lost``."""
        return self._last_heard_s is not None and not self.closed


class InProcessLink(MavlinkLink):
    """The companion's MAVLink link over :class:`InProcessIO` (no tlog: evaluation drops it)."""

    def __init__(self, cfg: LinkConfig, sitl: InProcessSitl, clock: Callable[[], float] = time.monotonic) -> None:
        cfg = cfg.model_copy(update={"connection": INPROCESS_CONNECTION})
        super().__init__(cfg, clock=clock)
        self.io = self._io = InProcessIO(cfg, sitl, self._clock)


class InProcessCamera:
    """A :class:`~companion.vision.camera.CameraSource` over the SITL's newest frame: the frame
    of the current lockstep frame is always there when the companion asks for it."""

    def __init__(self, sitl: InProcessSitl) -> None:
        self._sitl = sitl

    def open(self) -> None:
        pass

    def latest(self) -> Frame | None:
        return self._sitl.latest_frame

    def frame_at(self, time_boot_ms: int, timeout_s: float) -> Frame | None:
        frame = self._sitl.latest_frame
        return frame if frame is not None and frame.time_boot_ms >= time_boot_ms else None

    def close(self) -> None:
        pass


class InProcessSimulator(SimulatorClient):
    """:class:`SimulatorClient` over the in-process control surface (no socket)."""

    def __init__(self, sitl: InProcessSitl, io: InProcessIO) -> None:  # no super(): it would connect
        self._sitl, self._io = sitl, io

    def request(self, cmd: str, **args: Any) -> dict[str, Any]:
        reply = self._sitl.request({"cmd": cmd, **args})
        self._io.drain()  # what the request made the SITL say (STATUSTEXT) reaches the link now
        if not reply.get("ok"):
            raise SimulatorError(f"simulator refused {cmd!r}: {reply.get('error')}")
        return reply

    def close(self) -> None:
        pass


# ====================================================================== wiring
def sitl_config_for(companion: CompanionConfig, opts: RunOptions) -> SitlConfig:
    """The SITL ``start_sitl`` would run for ``opts``: the ``[sitl]`` tables of its config file,
    with ``opts.seed`` as the world's seed; ConfigError if it disagrees with ``companion`` about
    the world (companion/shared_facts.py)."""
    cfg = load_sitl_config(opts.config_path)
    check_shared_facts(companion, cfg)
    if opts.seed is None:
        return cfg
    return cfg.model_copy(update={"world": cfg.world.model_copy(update={"seed": opts.seed})})


def _check_inprocess(cfg: CompanionConfig, opts: RunOptions, lockstep: bool) -> None:
    """Only our own lockstep SITL and its camera can run in-process."""
    if opts.connection or opts.simulator:
        raise ConfigError("an in-process run flies its own SITL; it takes no --connect or --simulator")
    if not lockstep:
        raise ConfigError("an in-process run is lockstep only")
    if cfg.perception.camera.strip() != "auto":
        raise ConfigError(f"an in-process run sees the SITL's camera (camera = \"auto\"), not "
                          f"{cfg.perception.camera!r}; set [experiment] eval_inprocess = false")


class _OneOpenCVThread:
    """The SITL process renders with one OpenCV thread (``start_sitl``): a pool would spin on the
    other cores for a gain the lockstep loop cannot use. While any in-process run is open (runs
    may share a process, e.g. trials in threads), OpenCV uses one thread; then as before."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._users = 0
        self._before = 0

    @contextlib.contextmanager
    def __call__(self) -> Iterator[None]:
        import cv2

        with self._lock:
            if self._users == 0:
                self._before = cv2.getNumThreads()
                cv2.setNumThreads(1)
            self._users += 1
        try:
            yield
        finally:
            with self._lock:
                self._users -= 1
                if self._users == 0:
                    cv2.setNumThreads(self._before)


one_opencv_thread = _OneOpenCVThread()


@contextlib.contextmanager
def inprocess_vehicle(cfg: CompanionConfig, opts: RunOptions, lockstep: bool, run_dir: Path) -> Iterator[Vehicle]:
    """A :data:`~companion.app.VehicleOpener`: the connected in-process SITL, closed on exit."""
    _check_inprocess(cfg, opts, lockstep)
    with contextlib.ExitStack() as stack:
        stack.enter_context(one_opencv_thread())
        sitl = InProcessSitl(sitl_config_for(cfg, opts))
        stack.callback(sitl.close)
        link = InProcessLink(cfg.link, sitl)
        stack.callback(link.close)
        link.connect(timeout_s=30.0)
        camera = InProcessCamera(sitl) if sitl.camera is not None else None
        yield Vehicle(link, InProcessSimulator(sitl, link.io), camera, owned=True)
