"""Tests of the pilot console; ``stop`` ends a ``col console`` process a test started."""

from __future__ import annotations

import subprocess


def stop(proc: subprocess.Popen[bytes]) -> None:
    """SIGTERM (the console stops its run and its SITL), then SIGKILL if it hangs."""
    proc.terminate()
    try:
        proc.wait(30)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(10)
