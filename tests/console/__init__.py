"""Tests of the pilot console; ``start_col`` starts a ``col console`` (or ``col study``) process,
``stop`` ends it."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def start_console(run_dir: Path, log: Path, *extra: str) -> tuple[subprocess.Popen[bytes], str]:
    """``col console`` on a free port writing to ``run_dir`` (its log in ``log``): the process and
    the URL it printed."""
    return start_col(log, "console", "--port", "0", "--run-dir", str(run_dir), *extra)


def start_col(log: Path, *args: str) -> tuple[subprocess.Popen[bytes], str]:
    """``col ARGS``, a command that serves the console's page (its log in ``log``): the process and
    the URL it printed."""
    env = dict(os.environ, PYTHONPATH=str(REPO), OMP_NUM_THREADS="1")
    proc = subprocess.Popen([sys.executable, "-m", "companion.cli", *args], stdout=subprocess.PIPE,
                            stderr=log.open("ab"), env=env, cwd=REPO)
    assert proc.stdout is not None
    line = proc.stdout.readline().decode()
    if not line.startswith("CONSOLE "):
        stop(proc)
        raise AssertionError(log.read_text())
    return proc, line.split()[1]


def stop(proc: subprocess.Popen[bytes]) -> None:
    """SIGTERM (the console stops its run and its SITL), then SIGKILL if it hangs."""
    proc.terminate()
    try:
        proc.wait(30)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(10)
