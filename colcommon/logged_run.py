"""A command run for a results script, its output kept in a log file (the run's own record)."""

from __future__ import annotations

import subprocess
from pathlib import Path


def run_logged(cmd: list[str], log: Path, cwd: Path) -> None:
    """Run ``cmd`` in ``cwd`` with its output in ``log``; SystemExit naming the log if it fails
    (a long step that failed is rerun after a look at its log, not retried blindly)."""
    log.parent.mkdir(parents=True, exist_ok=True)
    with log.open("w") as out:
        done = subprocess.run(cmd, stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, cwd=cwd)
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({done.returncode}); see {log}")
