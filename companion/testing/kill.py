"""Killing processes on purpose: SIGKILL ``col fly`` or the SITL it flies mid-episode, and count
what the dataset kept. Shared by tests/reliability/test_killed.py and bench/faults.py."""

from __future__ import annotations

import glob
import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from companion.learning.dataset import load_csv


def col_command() -> list[str]:
    """The ``col`` console script beside this interpreter, else the module."""
    script = Path(sys.executable).with_name("col")
    return [str(script)] if script.exists() else [sys.executable, "-m", "companion.cli"]


def complete_rows(csv_path: Path) -> int:
    """Newline-terminated data rows on disk (what a killed writer had flushed)."""
    data = csv_path.read_bytes() if csv_path.exists() else b""
    return max(0, data.count(b"\n") - 1)


def samples_lost(csv_path: Path) -> int:
    """Flushed rows that do not load back (0 is the goal)."""
    return complete_rows(csv_path) - len(load_csv(csv_path).episode)


def children(pid: int) -> list[int]:
    out: list[int] = []
    for path in glob.glob(f"/proc/{pid}/task/*/children"):
        try:
            out += [int(x) for x in Path(path).read_text().split()]
        except OSError:
            continue
    return out


@dataclass
class ColRun:
    """A ``col fly`` process whose stderr is read (and timestamped) as it comes."""

    proc: subprocess.Popen[str]
    stderr: list[tuple[float, str]] = field(default_factory=list)

    @classmethod
    def start(cls, args: list[str]) -> ColRun:
        env = dict(os.environ, OMP_NUM_THREADS="1")
        proc = subprocess.Popen([*col_command(), "fly", *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                text=True, env=env)
        run = cls(proc)
        threading.Thread(target=run._read, daemon=True).start()
        return run

    def _read(self) -> None:
        assert self.proc.stderr is not None
        for line in self.proc.stderr:
            self.stderr.append((time.monotonic(), line.rstrip()))

    def first(self, text: str, after: float = float("-inf")) -> float | None:
        """When the first stderr line containing ``text`` arrived (at or after ``after``)."""
        return next((t for t, line in list(self.stderr) if text in line and t >= after), None)

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait(10)


def wait_rows(csv_path: Path, rows: int, timeout_s: float, proc: subprocess.Popen[str]) -> bool:
    """Until the dataset has ``rows`` flushed rows (False if the writer exits or time runs out)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline and proc.poll() is None:
        if complete_rows(csv_path) >= rows:
            return True
        time.sleep(0.005)
    return False


def sigkill(pid: int) -> float:
    """SIGKILL ``pid``; the monotonic time it was sent."""
    os.kill(pid, signal.SIGKILL)
    return time.monotonic()
