"""A loopback UDP proxy that makes a link bad on purpose: it drops, duplicates, reorders and
delays datagrams with seeded randomness, and can cut the link entirely (a blackout).

It sits between a vehicle and the companion::

    vehicle (sends to proxy.vehicle_port) <-> proxy <-> companion (udpin on companion_port)

The vehicle learns the proxy's vehicle-side address from the replies it gets, as it learns any
peer's; the companion sees the proxy's companion-side socket as the vehicle. Each direction has
its own :class:`LinkFaults`; everything is decided by one ``numpy`` generator, so a run is
reproducible for its seed (up to the operating system's scheduling).
"""

from __future__ import annotations

import heapq
import selectors
import socket
import threading
import time
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class LinkFaults:
    """What happens to each datagram going one way."""

    loss: float = 0.0  # probability it is dropped
    duplicate: float = 0.0  # probability it is sent twice
    reorder: float = 0.0  # probability it is held back and sent after the next one
    delay_s: float = 0.0  # extra latency, every datagram
    jitter_s: float = 0.0  # plus uniform 0..jitter_s

    def __post_init__(self) -> None:
        for name in ("loss", "duplicate", "reorder"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"LinkFaults.{name} is a probability in [0, 1]")
        if self.delay_s < 0 or self.jitter_s < 0:
            raise ValueError("LinkFaults delay_s and jitter_s must be >= 0")


@dataclass
class ProxyStats:
    forwarded: int = 0
    dropped: int = 0
    duplicated: int = 0
    reordered: int = 0
    blacked_out: int = 0


class LossyProxy:
    """Runs in its own thread from :meth:`start` until :meth:`close`."""

    def __init__(self, companion_port: int, to_companion: LinkFaults = LinkFaults(),
                 to_vehicle: LinkFaults = LinkFaults(), seed: int = 0, host: str = "127.0.0.1") -> None:
        self.faults = {"down": to_companion, "up": to_vehicle}
        self.rng = np.random.default_rng(seed)
        self.vehicle_side = self._socket(host)
        self.companion_side = self._socket(host)
        self.vehicle_port = self.vehicle_side.getsockname()[1]
        self.companion_addr = (host, companion_port)
        self.vehicle_addr: tuple[str, int] | None = None
        self.stats = {"down": ProxyStats(), "up": ProxyStats()}
        self.blackout = threading.Event()
        self._held: dict[str, tuple[socket.socket, tuple[str, int], bytes] | None] = {"down": None, "up": None}
        self._queue: list[tuple[float, int, socket.socket, tuple[str, int], bytes]] = []
        self._n = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="lossy-proxy", daemon=True)

    @staticmethod
    def _socket(host: str) -> socket.socket:
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 21)
        s.bind((host, 0))
        s.setblocking(False)
        return s

    def start(self) -> LossyProxy:
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(2.0)
        self.vehicle_side.close()
        self.companion_side.close()

    def __enter__(self) -> LossyProxy:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def cut(self, cut: bool = True) -> None:
        """Drop everything both ways (True) or restore the link (False)."""
        if cut:
            self.blackout.set()
        else:
            self.blackout.clear()

    # ----- the thread ----------------------------------------------------------------------
    def _run(self) -> None:
        sel = selectors.DefaultSelector()
        sel.register(self.vehicle_side, selectors.EVENT_READ, "down")
        sel.register(self.companion_side, selectors.EVENT_READ, "up")
        try:
            while not self._stop.is_set():
                timeout = 0.05 if not self._queue else max(0.0, min(0.05, self._queue[0][0] - time.monotonic()))
                for key, _ in sel.select(timeout):
                    self._read(key.fileobj, key.data)  # type: ignore[arg-type]
                self._release_due()
        finally:
            sel.close()

    def _read(self, sock: socket.socket, direction: str) -> None:
        while True:
            try:
                data, addr = sock.recvfrom(65535)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                continue  # ICMP unreachable from an earlier send
            if direction == "down":
                self.vehicle_addr = addr
                self._offer(direction, self.companion_side, self.companion_addr, data)
            elif self.vehicle_addr is not None:
                self._offer(direction, self.vehicle_side, self.vehicle_addr, data)

    def _offer(self, direction: str, out: socket.socket, dest: tuple[str, int], data: bytes) -> None:
        f, st = self.faults[direction], self.stats[direction]
        if self.blackout.is_set():
            st.blacked_out += 1
            return
        if self.rng.random() < f.loss:
            st.dropped += 1
            return
        copies = 2 if self.rng.random() < f.duplicate else 1
        st.duplicated += copies - 1
        held = self._held[direction]
        if held is None and self.rng.random() < f.reorder:
            self._held[direction] = (out, dest, data)
            st.reordered += 1
            return
        for _ in range(copies):
            self._schedule(f, out, dest, data)
        if held is not None:  # the held-back datagram goes after this one
            self._held[direction] = None
            self._schedule(f, *held)

    def _schedule(self, f: LinkFaults, out: socket.socket, dest: tuple[str, int], data: bytes) -> None:
        delay = f.delay_s + (self.rng.random() * f.jitter_s if f.jitter_s else 0.0)
        self._n += 1
        heapq.heappush(self._queue, (time.monotonic() + delay, self._n, out, dest, data))

    def _release_due(self) -> None:
        now = time.monotonic()
        while self._queue and self._queue[0][0] <= now:
            _, _, out, dest, data = heapq.heappop(self._queue)
            try:
                out.sendto(data, dest)
            except OSError:
                continue
            direction = "down" if out is self.companion_side else "up"
            self.stats[direction].forwarded += 1
