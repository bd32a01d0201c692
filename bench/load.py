"""A loaded machine on purpose, for the benches that measure under load."""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
from collections.abc import Iterator


@contextlib.contextmanager
def busy_processes(n: int, nice: int | None = None) -> Iterator[None]:
    """``n`` CPU-bound processes for the block (at ``nice``, if given: CI's other tests, roughly,
    whatever the bench's own niceness)."""
    def set_nice() -> None:
        if nice is not None:
            os.setpriority(os.PRIO_PROCESS, 0, nice)

    procs = [subprocess.Popen([sys.executable, "-c", "while True: pass"], preexec_fn=set_nice) for _ in range(n)]
    try:
        yield
    finally:
        for p in procs:
            p.kill()
            p.wait()
