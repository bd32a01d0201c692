"""The SITL's transports: MAVLink over UDP port pairs and TCP connections, and the control
surface's JSON lines over TCP.

Sockets only, never the simulation: a client parses what arrives and queues what is sent, the
server (sitl/server.py) decides what that is and when. Everything is non-blocking, served by
the server's one selector, so a slow or vanished peer never stalls the frame loop.
"""

from __future__ import annotations

import ipaddress
import json
import logging
import selectors
import socket
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

from sitl.signing import SitlSigning

log = logging.getLogger("sitl.server")
M = mavlink
MAX_TCP_BACKLOG_BYTES = 1 << 20
CONTROL_REPLY_TIMEOUT_S = 1.0
UDP_PAYLOAD_BYTES = 1472  # one Ethernet MTU: what a real radio or network link carries
MAX_CONTROL_LINE_BYTES = 1 << 16


def listener(host: str, port: int) -> socket.socket:
    """A non-blocking TCP listening socket (``port`` 0: any free port)."""
    s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    s.bind((host, port))
    s.listen(8)
    s.setblocking(False)
    return s


class MavClient:
    """One MAVLink peer (a UDP port pair or a TCP connection) with its own parser."""

    name: str
    secure = False  # may set a first signing key (SETUP_SIGNING): a wired link
    signing: SitlSigning | None = None

    def __init__(self) -> None:
        self._new_parser()
        self.active = False  # has the peer ever talked to us?
        self.bad_packets = 0
        self.signed_peer = False  # a validly signed message came in: only signed ones redirect us

    def use_signing(self, signing: SitlSigning) -> None:
        self.signing = signing
        self._new_parser()

    def _new_parser(self) -> None:
        self.parser = M.MAVLink(None, 0, 0)
        self.parser.robust_parsing = True
        if self.signing is not None:  # shared state: a parser reset never forgets a stream
            self.signing.attach(self.parser)

    def adopts_sender(self, msgs: list[mavlink.MAVLink_message]) -> bool:
        """May these messages make their sender our peer? With signing required, once a signed
        peer talked, only signed messages can (an unsigned sender cannot take its telemetry)."""
        if any(m.get_signed() for m in msgs):
            self.signed_peer = True
            return True
        return self.signing is None or not self.signing.required or not self.signed_peer

    def parse(self, data: bytes) -> list[mavlink.MAVLink_message]:
        try:
            msgs = self.parser.parse_buffer(data) or []
        except Exception:  # noqa: BLE001 - pymavlink raises bare exceptions on garbage
            self.bad_packets += 1
            self._new_parser()
            return []
        good = [m for m in msgs if m.get_type() != "BAD_DATA"]
        self.bad_packets += len(msgs) - len(good)
        return good

    def send(self, data: bytes) -> None:
        raise NotImplementedError

    def flush(self) -> None:
        """Push out anything queued by :meth:`send` (a no-op for unbuffered transports)."""

    def close(self) -> None:
        raise NotImplementedError


class UdpClient(MavClient):
    """A local UDP port that sends to a default remote until a peer talks to it (as PX4)."""

    def __init__(self, host: str, local_port: int, remote_port: int) -> None:
        super().__init__()
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 1 << 20)
        self.sock.bind((host, local_port))
        self.sock.setblocking(False)
        self.local_port = self.sock.getsockname()[1]
        self.remote = (host, remote_port)
        self.outbox = bytearray()
        self.name = f"udp:{self.local_port}->{remote_port}"

    def read(self) -> list[mavlink.MAVLink_message]:
        msgs: list[mavlink.MAVLink_message] = []
        while True:
            try:
                data, addr = self.sock.recvfrom(65535)
            except (BlockingIOError, InterruptedError):
                return msgs
            except OSError:  # ICMP port unreachable from an earlier send: nobody listening
                continue
            new = self.parse(data)
            if self.adopts_sender(new):
                self.remote = addr
                self.active = True
            msgs.extend(new)
            if len(self.parser.buf) > self.parser.buf_index:  # a datagram is whole: drop leftovers
                self._new_parser()

    def send(self, data: bytes) -> None:
        """Queue ``data``; :meth:`flush` packs queued messages into few datagrams, as PX4 does."""
        if len(self.outbox) + len(data) > UDP_PAYLOAD_BYTES:
            self.flush()
        self.outbox += data

    def flush(self) -> None:
        if not self.outbox:
            return
        try:
            self.sock.sendto(self.outbox, self.remote)
        except OSError:
            pass  # nobody listening there (yet): a real autopilot keeps sending too
        self.outbox = bytearray()

    def close(self) -> None:
        self.sock.close()


class TcpClient(MavClient):
    """An accepted TCP connection; a client that cannot keep up is dropped, never waited for."""

    def __init__(self, sock: socket.socket, addr: tuple[str, int]) -> None:
        super().__init__()
        self.secure = ipaddress.ip_address(addr[0]).is_loopback  # a wire to this machine, like USB
        self.sock = sock
        self.sock.setblocking(False)
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.name = f"tcp:{addr[0]}:{addr[1]}"
        self.pending = b""
        self.closed = False
        self.active = True

    def read(self) -> list[mavlink.MAVLink_message]:
        try:
            data = self.sock.recv(65536)
        except (BlockingIOError, InterruptedError):
            return []
        except OSError:
            data = b""
        if not data:
            self.closed = True
            return []
        return self.parse(data)

    def send(self, data: bytes) -> None:
        if self.closed:
            return
        self.pending += data
        try:
            sent = self.sock.send(self.pending)
            self.pending = self.pending[sent:]
        except (BlockingIOError, InterruptedError):
            pass
        except OSError:
            self.closed = True
        if len(self.pending) > MAX_TCP_BACKLOG_BYTES:
            log.warning("%s cannot keep up; dropping it", self.name)
            self.closed = True

    def close(self) -> None:
        self.closed = True
        self.sock.close()


@dataclass
class ControlClient:
    sock: socket.socket
    buffer: bytes = b""
    closed: bool = False


class ControlChannel:
    """The control surface's connections: each sends JSON lines, which wait in one queue until
    the server takes them (between frames only, so an episode reset never lands in a frame)."""

    def __init__(self, sel: selectors.BaseSelector, sock: socket.socket, on_data: Callable[[], None]) -> None:
        """``sock``: the listening socket; ``on_data``: told after each read (between frames the
        server answers at once)."""
        self.sel = sel
        self.listener = sock
        self.on_data = on_data
        self.queue: deque[tuple[ControlClient, bytes]] = deque()
        sel.register(sock, selectors.EVENT_READ, self._accept)

    def _accept(self) -> None:
        try:
            sock, _ = self.listener.accept()
        except OSError:
            return
        sock.setblocking(False)
        cc = ControlClient(sock)
        self.sel.register(sock, selectors.EVENT_READ, lambda cc=cc: self._read(cc))

    def _read(self, cc: ControlClient) -> None:
        try:
            data = cc.sock.recv(65536)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            data = b""
        if not data or len(cc.buffer) > MAX_CONTROL_LINE_BYTES:
            self.close_client(cc)
            return
        cc.buffer += data
        while b"\n" in cc.buffer and not cc.closed:
            line, cc.buffer = cc.buffer.split(b"\n", 1)
            if line.strip():
                self.queue.append((cc, line))
        self.on_data()

    def next_request(self) -> tuple[ControlClient, bytes] | None:
        """The oldest queued request of a client still connected, or None."""
        while self.queue:
            cc, line = self.queue.popleft()
            if not cc.closed:
                return cc, line
        return None

    def reply(self, cc: ControlClient, reply: dict[str, Any]) -> None:
        """Send one reply, bounded: a client that never reads its replies must not stall the
        simulation; it is closed instead."""
        try:
            cc.sock.settimeout(CONTROL_REPLY_TIMEOUT_S)
            cc.sock.sendall((json.dumps(reply) + "\n").encode())
            cc.sock.setblocking(False)
        except OSError:
            log.warning("control client does not take its replies; closing it")
            self.close_client(cc)

    def close_client(self, cc: ControlClient) -> None:
        if cc.closed:
            return
        cc.closed = True
        try:
            self.sel.unregister(cc.sock)
        except (KeyError, ValueError):
            pass
        cc.sock.close()
