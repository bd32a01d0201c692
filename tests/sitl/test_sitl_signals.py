"""A SITL stops on SIGTERM however many arrive at once (a parent's death and a kill together)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

from tests.conftest import free_port

REPO = Path(__file__).resolve().parents[2]


def test_a_burst_of_sigterms_stops_the_sitl() -> None:
    """Each SIGTERM used to call the server's stop() inside the handler; one arriving while the
    last was inside Event.set waited for the lock its own thread held, and the SITL never ended."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "sitl", "--clock", "lockstep", "--udp", f"0:{free_port()}", "--tcp", "-1",
         "--camera-port", "0", "--control-port", "0"],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
    )
    try:
        assert proc.stdout is not None and proc.stdout.readline().startswith("READY")
        for _ in range(300):
            os.kill(proc.pid, signal.SIGTERM)
        assert proc.wait(timeout=20) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
