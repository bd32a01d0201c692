"""An asyncio event loop on a dedicated thread, driven from synchronous code.

The MAVSDK backend is asyncio; the companion's control loop is a plain thread. This bridges
the two the way Gymnasium's async vector env bridges processes: explicit start and stop,
timeouts on every wait, and errors re-raised in the caller.
"""

from __future__ import annotations

import asyncio
import threading
from collections.abc import Coroutine
from concurrent.futures import Future
from concurrent.futures import TimeoutError as FutureTimeout
from typing import Any, TypeVar

T = TypeVar("T")


class AsyncRunner:
    """Runs coroutines on its own loop thread; ``run`` waits, ``spawn`` does not."""

    def __init__(self, name: str = "asyncio-runner") -> None:
        self.loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._main, name=name, daemon=True)
        self._thread.start()

    def _main(self) -> None:
        asyncio.set_event_loop(self.loop)
        self.loop.run_forever()

    def run(self, coro: Coroutine[Any, Any, T], timeout_s: float) -> T:
        """The coroutine's result; TimeoutError (coroutine cancelled) after ``timeout_s``."""
        future = asyncio.run_coroutine_threadsafe(coro, self.loop)
        try:
            return future.result(timeout=timeout_s)
        except FutureTimeout:
            future.cancel()
            raise TimeoutError(f"no result within {timeout_s} s") from None

    def spawn(self, coro: Coroutine[Any, Any, Any]) -> Future[Any]:
        """Start a background coroutine (a stream); cancel it with the returned future."""
        return asyncio.run_coroutine_threadsafe(coro, self.loop)

    @property
    def running(self) -> bool:
        return self._thread.is_alive()

    def stop(self, timeout_s: float = 2.0) -> None:
        """Cancel what is left, stop the loop and join its thread. Idempotent."""
        if not self._thread.is_alive():
            return
        try:
            self.run(self._cancel_all(), timeout_s)
        except (TimeoutError, RuntimeError):
            pass
        self.loop.call_soon_threadsafe(self.loop.stop)
        self._thread.join(timeout=timeout_s)
        if not self._thread.is_alive():
            self.loop.close()

    @staticmethod
    async def _cancel_all() -> None:
        current = asyncio.current_task()
        tasks = [t for t in asyncio.all_tasks() if t is not current]
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
