"""Waiting on the I/O thread for a message that answers a request (COMMAND_ACK, PARAM_VALUE).

A waiter is registered *before* the request is sent, so an answer that arrives quickly is
never missed; the I/O thread offers every received message to the registered waiters.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable
from typing import Any

Predicate = Callable[[Any], bool]


class Waiter:
    """Collects the messages that match one predicate."""

    def __init__(self, predicate: Predicate) -> None:
        self.predicate = predicate
        self._queue: queue.SimpleQueue[Any] = queue.SimpleQueue()

    def offer(self, msg: Any) -> None:
        if self.predicate(msg):
            self._queue.put(msg)

    def get(self, timeout_s: float) -> Any | None:
        """The next matching message, or None after ``timeout_s``."""
        try:
            return self._queue.get(timeout=max(0.0, timeout_s))
        except queue.Empty:
            return None


class Waiters:
    """The set of waiters the I/O thread feeds."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._waiters: list[Waiter] = []

    def add(self, predicate: Predicate) -> Waiter:
        waiter = Waiter(predicate)
        with self._lock:
            self._waiters.append(waiter)
        return waiter

    def remove(self, waiter: Waiter) -> None:
        with self._lock:
            if waiter in self._waiters:
                self._waiters.remove(waiter)

    def offer(self, msg: Any) -> None:
        with self._lock:
            waiters = list(self._waiters)
        for waiter in waiters:
            waiter.offer(msg)
