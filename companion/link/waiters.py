"""Waiting on the I/O thread: for a message that answers a request (COMMAND_ACK, PARAM_VALUE),
or for the newest vehicle snapshot to pass a test (:func:`wait_until`).

A waiter is registered *before* the request is sent, so an answer that arrives quickly is
never missed; the I/O thread offers every received message to the registered waiters.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable
from typing import Any, TypeVar

Predicate = Callable[[Any], bool]
T = TypeVar("T")


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


def wait_until(changed: threading.Condition, current: Callable[[], T], ready: Callable[[T], bool],
               timeout_s: float, clock: Callable[[], float], closed: Callable[[], bool],
               on_idle: Callable[[], None] | None = None) -> T | None:
    """``current()`` once ``ready`` holds for it, waiting on ``changed`` (which the I/O thread
    notifies with every new value, under its lock) and looking again at least every 50 ms; None
    after ``timeout_s`` by ``clock`` or once ``closed()``. ``on_idle`` runs before each wait
    (a link's loss check: it may raise)."""
    deadline = clock() + timeout_s
    with changed:
        while not ready(value := current()):
            remaining = deadline - clock()
            if remaining <= 0 or closed():
                return None
            if on_idle is not None:
                on_idle()
            changed.wait(min(remaining, 0.05))
        return value
