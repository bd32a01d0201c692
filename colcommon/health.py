"""Container health probes for both services (``compose.yaml``), with arguments free of spaces
because some container engines split a health check's command on them:

    python3 -m colcommon.health tcp HOST PORT        healthy when HOST:PORT accepts a connection
    python3 -m colcommon.health fresh FILE SECONDS   healthy when FILE was written SECONDS ago or less

Exit status 0 is healthy, 1 is not (the reason on stderr), 2 is a usage error.
"""

from __future__ import annotations

import os
import socket
import sys
import time


def tcp_accepts(host: str, port: int, timeout_s: float = 2.0) -> str | None:
    """None when ``host:port`` accepts a TCP connection, else why not."""
    try:
        socket.create_connection((host, port), timeout_s).close()
    except OSError as exc:
        return f"{host}:{port} does not accept connections ({exc})"
    return None


def written_within(path: str, seconds: float) -> str | None:
    """None when ``path`` exists and was modified at most ``seconds`` ago, else why not."""
    try:
        age = time.time() - os.path.getmtime(path)
    except OSError:
        return f"{path} does not exist yet"
    return None if age <= seconds else f"{path} last written {age:.0f} s ago"


def main(argv: list[str]) -> int:
    try:
        kind, target, value = argv
        problem = tcp_accepts(target, int(value)) if kind == "tcp" else (
            written_within(target, float(value)) if kind == "fresh" else "usage")
    except ValueError:
        problem = "usage"
    if problem == "usage":
        print(__doc__, file=sys.stderr)
        return 2
    if problem is not None:
        print(f"unhealthy: {problem}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
