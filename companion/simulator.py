"""The companion's side of the SITL: starting it as a process and using its control surface.

A real vehicle has no control surface; everything here is optional for the session, which
falls back to flying episode starts itself when no simulator is attached.
"""

from __future__ import annotations

import json
import logging
import os
import select
import socket
import subprocess
import sys
import threading
import time
from collections import deque
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from companion.errors import SimulatorError

logger = logging.getLogger(__name__)

# how long a killed SITL may take to exit before a stop gives up waiting (SIGKILL cannot be refused;
# only a machine too busy to run the exit can delay it)
KILL_REAP_S = 10.0


class SimulatorClient:
    """JSON-lines client of the SITL's control surface (docs/protocols.md)."""

    def __init__(self, host: str, port: int, timeout_s: float = 10.0, token: str | None = None) -> None:
        """``token``: the SITL's control token, when it listens beyond loopback (docs/reliability.md)."""
        self._auth = {"token": token} if token else {}
        self.address = f"{host}:{port}"
        self._host, self._port, self._timeout_s = host, port, timeout_s
        self._lock = threading.Lock()
        self._sock: socket.socket | None = None
        self._file: Any = None
        self._connect()

    def _connect(self) -> None:
        try:
            self._sock = socket.create_connection((self._host, self._port), timeout=self._timeout_s)
        except OSError as exc:
            raise SimulatorError(f"cannot reach the simulator control surface at {self.address}: {exc}; "
                                 "is the SITL running?") from exc
        self._file = self._sock.makefile("rb")

    def request(self, cmd: str, **args: Any) -> dict[str, Any]:
        """Send one request and return its reply; a refusal raises SimulatorError.

        A request that fails midway (a timeout: a frozen or starved SITL) leaves its reply on the
        way; the next request would read it as its own. So the connection is dropped and the
        next request opens a new one."""
        with self._lock:
            try:
                if self._sock is None:
                    self._connect()
                assert self._sock is not None
                self._sock.sendall((json.dumps({"cmd": cmd, **args, **self._auth}) + "\n").encode())
                line = self._file.readline()
            except OSError as exc:
                self._drop()
                raise SimulatorError(f"simulator control surface failed during {cmd!r}: {exc}") from exc
            if not line:
                self._drop()
                raise SimulatorError(f"simulator closed the control connection during {cmd!r}")
        reply = json.loads(line)
        if not reply.get("ok"):
            raise SimulatorError(f"simulator refused {cmd!r}: {reply.get('error')}")
        return reply

    def _drop(self) -> None:
        sock, file, self._sock, self._file = self._sock, self._file, None, None
        for closable in (file, sock):
            try:
                if closable is not None:
                    closable.close()
            except OSError:
                pass

    def info(self) -> dict[str, Any]:
        return self.request("info")

    def reset(self, seed: int | None = None) -> dict[str, Any]:
        return self.request("reset", seed=seed)

    def truth(self) -> dict[str, Any]:
        return self.request("truth")

    def close(self) -> None:
        """Without the lock: closing ends a request that waits on a silent SITL."""
        self._drop()


@dataclass
class SitlProcess:
    """A running ``col-sitl`` and the ports it bound.

    After READY its output is drained on background threads into a short tail, so a chatty SITL
    can never block on a full pipe (which would stall a lockstep run).
    """

    proc: subprocess.Popen[bytes]
    ports: dict[str, Any]
    tail: deque[str] = field(default_factory=lambda: deque(maxlen=200))

    def drain(self) -> None:
        for stream in (self.proc.stdout, self.proc.stderr):
            if stream is not None:
                threading.Thread(target=self._read_lines, args=(stream,), name="sitl-output", daemon=True).start()

    def _read_lines(self, stream: Any) -> None:
        try:
            for line in iter(stream.readline, b""):
                self.tail.append(line.decode(errors="replace").rstrip())
        except (OSError, ValueError):
            return  # closed by stop()

    def _reaped(self, timeout_s: float) -> bool:
        try:
            self.proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            return False
        return True

    @property
    def control_port(self) -> int:
        return int(self.ports["control"])

    def stop(self, timeout_s: float = 5.0) -> None:
        """Ask the SITL to stop, kill it after ``timeout_s``, and never raise: a stop runs while a
        run unwinds (Ctrl-C, SIGTERM, an error), and what unwinds must reach its end, where the
        data is kept. A killed SITL that a loaded machine has not yet reaped (once more than 5 s
        after SIGKILL in CI) is left to the kernel with a warning."""
        if self.proc.poll() is None:
            self.proc.terminate()
            if not self._reaped(timeout_s):
                logger.warning("the SITL (pid %d) did not stop within %.0f s of SIGTERM: killed", self.proc.pid, timeout_s)
                self.proc.kill()
                if not self._reaped(KILL_REAP_S):
                    logger.warning("the killed SITL (pid %d) had not exited %.0f s later; left to the kernel",
                                   self.proc.pid, KILL_REAP_S)
        for stream in (self.proc.stdout, self.proc.stderr):
            if stream is not None:
                stream.close()


def start_sitl(
    udp_remote_port: int,
    clock: str = "lockstep",
    config: str | Path | None = None,
    seed: int | None = None,
    camera: bool = True,
    extra_args: list[str] | None = None,
    timeout_s: float = 120.0,
    nice: int | None = None,
) -> SitlProcess:
    """Start the SITL in another process on free loopback ports, sending MAVLink to
    ``udp_remote_port``; returns once it reports READY.

    In lockstep the SITL runs ``nice`` (default 10) steps below the companion: on one machine it
    would otherwise take the companion's core while computing the next frame (a real autopilot
    has its own processor), and it waits for the companion anyway, so this costs no throughput.
    In real time it keeps the companion's priority (default 0): it has a wall clock to keep, and
    behind a busy machine's other work it fell behind it. ``timeout_s`` is only an upper bound
    (a loaded machine took over 30 s to import and start it). It also stops when the thread
    that started it ends (Linux): start it from a thread that lives as long as it."""
    if nice is None:
        nice = 10 if clock == "lockstep" else 0
    args = [sys.executable, "-m", "sitl", "--clock", clock, "--udp", f"0:{udp_remote_port}", "--tcp", "-1",
            "--camera-port", "0", "--control-port", "0", "--exit-with-parent"]
    if config is not None:
        args += ["--config", str(config)]
    if seed is not None:
        args += ["--seed", str(seed)]
    if not camera:
        args.append("--no-camera")
    args += extra_args or []
    # one thread per library: OpenCV's own pool (2 workers on 2 cores) spun for warpPerspective
    # in every frame, 0.1-0.8 ms of CPU per frame for a wall-time gain the lockstep loop cannot use
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENCV_FOR_THREADS_NUM="1")
    # unbuffered: select() below must see every byte not yet read
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env, bufsize=0)
    try:
        _lower_priority(proc.pid, nice)
        sitl = SitlProcess(proc, _wait_ready(proc, timeout_s))
        sitl.drain()
        return sitl
    except BaseException:  # refused, too slow, or Ctrl-C meanwhile: leave no SITL behind
        SitlProcess(proc, {}).stop()
        raise


def _wait_ready(proc: subprocess.Popen[bytes], timeout_s: float) -> dict[str, Any]:
    """The ports of the SITL's ``READY {json}`` line; SimulatorError if it exits or is too slow."""
    assert proc.stdout is not None
    deadline = time.monotonic() + timeout_s
    while (remaining := deadline - time.monotonic()) > 0:
        if not select.select([proc.stdout], [], [], remaining)[0]:
            break
        line = proc.stdout.readline()
        if not line:
            err = proc.stderr.read().decode(errors="replace") if proc.stderr else ""
            raise SimulatorError(f"the SITL exited before it was ready:\n{err[-2000:]}")
        if line.startswith(b"READY "):
            return dict(json.loads(line[6:]))
    raise SimulatorError(f"the SITL did not report READY within {timeout_s} s; the machine may be "
                         "overloaded, or run col-sitl by hand to see why")


def _lower_priority(pid: int, nice: int) -> None:
    if nice <= 0 or not hasattr(os, "setpriority"):
        return
    try:
        os.setpriority(os.PRIO_PROCESS, pid, os.getpriority(os.PRIO_PROCESS, pid) + nice)
    except OSError:
        pass  # not permitted here: the SITL just competes for the CPU as before


@contextmanager
def running_sitl(udp_remote_port: int, **kwargs: Any) -> Iterator[SitlProcess]:
    """``start_sitl`` as a context manager that always stops the process."""
    sitl = start_sitl(udp_remote_port, **kwargs)
    try:
        yield sitl
    finally:
        sitl.stop()
