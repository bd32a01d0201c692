"""The control surface's client: a request that timed out never hands its late reply to the next."""

from __future__ import annotations

import json
import socket
import threading
from collections.abc import Iterator

import pytest

from companion.errors import SimulatorError
from companion.simulator import SimulatorClient


@pytest.fixture
def slow_first_reply() -> Iterator[tuple[int, threading.Event, list[str]]]:
    """A control surface on loopback that answers its first request only when told to (a frozen
    SITL that wakes up), and every later one at once; each reply names the request it answers."""
    listener = socket.create_server(("127.0.0.1", 0))
    release, seen = threading.Event(), []

    def serve() -> None:
        while True:
            try:
                conn, _ = listener.accept()
            except OSError:
                return
            threading.Thread(target=answer, args=(conn,), daemon=True).start()

    def answer(conn: socket.socket) -> None:
        with conn, conn.makefile("rb") as lines:
            for line in lines:
                cmd = json.loads(line)["cmd"]
                if not seen:
                    release.wait(10)
                seen.append(cmd)
                try:
                    conn.sendall((json.dumps({"ok": True, "answers": cmd}) + "\n").encode())
                except OSError:
                    return

    threading.Thread(target=serve, daemon=True).start()
    yield listener.getsockname()[1], release, seen
    release.set()
    listener.close()


def test_a_timed_out_request_does_not_desynchronise_the_next(slow_first_reply) -> None:  # type: ignore[no-untyped-def]
    port, release, seen = slow_first_reply
    client = SimulatorClient("127.0.0.1", port, timeout_s=0.2)
    try:
        with pytest.raises(SimulatorError, match="failed during 'truth'"):
            client.truth()
        release.set()  # the frozen SITL wakes up and sends the late reply to 'truth'
        assert client.reset(3)["answers"] == "reset"  # its own reply, on a new connection
        assert client.truth()["answers"] == "truth"
    finally:
        client.close()
