"""The containers' health probes (colcommon.health), as compose runs them."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def probe(*args: str) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ, PYTHONPATH=str(REPO))
    return subprocess.run([sys.executable, "-m", "colcommon.health", *args], env=env, capture_output=True,
                          text=True, timeout=30)


def test_tcp_probe_tells_a_listening_port_from_a_closed_one() -> None:
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen()
        port = server.getsockname()[1]
        assert probe("tcp", "127.0.0.1", str(port)).returncode == 0
    closed = probe("tcp", "127.0.0.1", str(port))
    assert closed.returncode == 1 and "does not accept" in closed.stderr


def test_fresh_probe_follows_the_file_age(tmp_path: Path) -> None:
    log = tmp_path / "session.tlog"
    assert probe("fresh", str(log), "20").returncode == 1
    log.write_bytes(b"x")
    assert probe("fresh", str(log), "20").returncode == 0
    old = time.time() - 60
    os.utime(log, (old, old))
    stale = probe("fresh", str(log), "20")
    assert stale.returncode == 1 and "60 s ago" in stale.stderr


def test_bad_usage_exits_2_with_help() -> None:
    done = probe("udp", "x")
    assert done.returncode == 2 and "colcommon.health tcp" in done.stderr
