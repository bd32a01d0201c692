"""The SITL's camera stream server (docs/protocols.md, "Camera stream"): frames in the wire
format of :mod:`colcommon.frames`, to every connected reader, newest frame wins.
"""

from __future__ import annotations

import contextlib
import socket
import threading

from colcommon.frames import ENCODINGS, Frame, encode_frame


class _Client:
    """One connected reader with its own writer thread and a one-frame mailbox (newest wins)."""

    def __init__(self, sock: socket.socket, write_timeout_s: float) -> None:
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.settimeout(write_timeout_s)
        self.sock = sock
        self.alive = True
        self._cond = threading.Condition()
        self._pending: bytes | None = None
        self._pending_seq = 0
        self._sent_seq = 0
        self._thread = threading.Thread(target=self._run, name="colf-writer", daemon=True)
        self._thread.start()

    def offer(self, data: bytes, seq: int) -> None:
        with self._cond:
            self._pending, self._pending_seq = data, seq
            self._cond.notify_all()

    def wait_sent(self, seq: int, timeout_s: float) -> bool:
        """True once frame ``seq`` (or a newer one) is completely written."""
        with self._cond:
            self._cond.wait_for(lambda: self._sent_seq >= seq or not self.alive, timeout_s)
            return self._sent_seq >= seq

    def close(self) -> None:
        with self._cond:
            self.alive = False
            self._cond.notify_all()
        with contextlib.suppress(OSError):
            self.sock.shutdown(socket.SHUT_RDWR)
        self.sock.close()

    def join(self, timeout_s: float) -> None:
        self._thread.join(timeout_s)

    def _run(self) -> None:
        while True:
            with self._cond:
                self._cond.wait_for(lambda: self._pending is not None or not self.alive)
                if not self.alive:
                    return
                data, seq, self._pending = self._pending, self._pending_seq, None
            assert data is not None
            try:
                self.sock.sendall(data)
            except OSError:  # reader gone, or too slow for write_timeout_s: the stream is broken
                self.close()
                return
            with self._cond:
                self._sent_seq = seq
                self._cond.notify_all()


class FrameServer:
    """Serves camera frames to any number of TCP readers on loopback (``colf://host:port``).

    ``publish(frame, blocking=True)`` (lockstep) returns once every reader has the whole frame;
    a reader that takes longer than ``write_timeout_s`` is dropped so the simulation never hangs.
    ``blocking=False`` (real time) only hands the frame to each reader's writer thread: a slow
    reader skips frames and never stalls the caller. Dead readers are removed.
    """

    def __init__(
        self, host: str = "127.0.0.1", port: int = 0, encoding: str = "raw",
        jpeg_quality: int = 90, write_timeout_s: float = 2.0,
    ) -> None:
        if encoding not in ENCODINGS:
            raise ValueError(f"encoding must be one of {sorted(ENCODINGS)}, got {encoding!r}")
        self.encoding, self.jpeg_quality, self.write_timeout_s = encoding, jpeg_quality, write_timeout_s
        self._listener = socket.create_server((host, port))
        self._listener.settimeout(0.1)
        self.host = host
        self.port: int = self._listener.getsockname()[1]
        self._clients: list[_Client] = []
        self._lock = threading.Lock()
        self._closed = threading.Event()
        self._seq = 0
        self._accept_thread = threading.Thread(target=self._accept_loop, name="colf-accept", daemon=True)
        self._accept_thread.start()

    @property
    def uri(self) -> str:
        return f"colf://{self.host}:{self.port}"

    @property
    def client_count(self) -> int:
        with self._lock:
            return sum(c.alive for c in self._clients)

    def publish(self, frame: Frame, blocking: bool) -> None:
        """Send ``frame`` to every connected reader (see the class docstring)."""
        with self._lock:
            self._clients = [c for c in self._clients if c.alive]
            clients = list(self._clients)
        if not clients:
            return
        data = encode_frame(frame, self.encoding, self.jpeg_quality)
        self._seq += 1
        for client in clients:
            client.offer(data, self._seq)
        if blocking:
            for client in clients:
                if not client.wait_sent(self._seq, self.write_timeout_s):
                    client.close()

    def close(self) -> None:
        """Stop accepting, disconnect every reader and join the threads."""
        self._closed.set()
        self._accept_thread.join(1.0)
        self._listener.close()
        with self._lock:
            clients, self._clients = self._clients, []
        for client in clients:
            client.close()
            client.join(1.0)

    def __enter__(self) -> FrameServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _accept_loop(self) -> None:
        while not self._closed.is_set():
            try:
                sock, _ = self._listener.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            client = _Client(sock, self.write_timeout_s)
            with self._lock:
                if self._closed.is_set():
                    client.close()
                    return
                self._clients.append(client)
