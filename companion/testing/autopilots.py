"""Real autopilots in SITL for tests: PX4 with its built-in SIH quadrotor, and ArduCopter.

They are prebuilt from upstream source (not installed by pip): the folder named by
``COL_AUTOPILOTS``, else ``shared/autopilots`` beside the checkout. :func:`find_autopilots`
says where they are or why not; :func:`start_px4` and :func:`start_ardupilot` start one instance
on ports of its own, in a fresh working folder, and return how the companion connects to it.
Both run in real time, or ``speedup`` times faster (wait on them by their own clock then:
:mod:`companion.testing.vehicle_time`); stop them with :meth:`RunningAutopilot.stop` (a context manager).

The PX4 build's ``bin/px4-<module>`` commands are symbolic links to ``px4`` upstream; a copy
that lost the links (each file holds the text ``px4``) is repaired in the working folder, so
the start script's module commands run.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import signal
import socket
import subprocess
import tempfile
import threading
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

ENV_VAR = "COL_AUTOPILOTS"
REPO_ROOT = Path(__file__).resolve().parents[2]
HOW_TO_GET = (f"set {ENV_VAR} to a folder with px4/ (PX4 SITL, SIH: `make px4_sitl sihsim_quadx`) "
              "and ardupilot/ (ArduCopter SITL: `./waf configure --board sitl && ./waf copter`), "
              "laid out as shared/autopilots beside the checkout")
PX4_OFFBOARD_PORT = 14540  # PX4 sends its onboard (API) link here, + instance
PX4_GCS_PORT = 14550
PX4_LOCAL_PORTS = (14580, 18570, 14280, 13030, 19450)  # what PX4's mavlink instances bind, + instance
ARDUPILOT_TCP_PORT = 5760  # + 10 x instance; serial 1 and 2 on +2, +3
ARDUPILOT_SIM_PORTS = (5501, 5502, 5503)  # + 10 x instance: its simulator's own sockets
Kind = Literal["px4", "ardupilot"]


def find_autopilots() -> tuple[Path | None, str]:
    """(folder, "") when the autopilots are there; (None, why not and how to get them) otherwise."""
    named = os.environ.get(ENV_VAR)
    root = Path(named) if named else REPO_ROOT.parent / "shared" / "autopilots"
    missing = [str(root / p) for p in ("px4/bin/px4", "px4/etc", "ardupilot/arducopter") if not (root / p).exists()]
    if missing:
        origin = f"{ENV_VAR}={named}" if named else "no COL_AUTOPILOTS, and beside the checkout"
        return None, f"real autopilots not found ({origin}: missing {', '.join(missing)}); {HOW_TO_GET}"
    return root, ""


@dataclass
class RunningAutopilot:
    """One started autopilot: how to connect, its log, and how to stop it."""

    kind: Kind
    instance: int
    process: subprocess.Popen[bytes]
    connection: str  # for the companion, e.g. udpin:127.0.0.1:14541
    workdir: Path
    log_path: Path
    _log: object = field(repr=False, default=None)

    def alive(self) -> bool:
        return self.process.poll() is None

    def log_tail(self, lines: int = 30) -> str:
        try:
            return "\n".join(self.log_path.read_text(errors="replace").splitlines()[-lines:])
        except OSError:
            return ""

    def stop(self, timeout_s: float = 10.0) -> None:
        """SIGTERM to its process group, then SIGKILL if it lingers. Idempotent."""
        if self.process.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(self.process.pid, signal.SIGTERM)
            try:
                self.process.wait(timeout_s)
            except subprocess.TimeoutExpired:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(self.process.pid, signal.SIGKILL)
                self.process.wait(timeout_s)
        close = getattr(self._log, "close", None)
        if close is not None:
            close()
        _release(self.kind, self.instance)

    def __enter__(self) -> RunningAutopilot:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


def udp_port_free(port: int) -> bool:
    """Whether a UDP socket can bind ``port`` on 127.0.0.1 right now."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def _tcp_free(port: int) -> bool:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


_CLAIMED: dict[tuple[str, int], int] = {}
_CLAIM_LOCK = threading.Lock()
"""Instances handed out and not stopped yet, each with the descriptor of its lock file. Two
started at once would both find the same ports free before either binds them (ArduCopter then
fails: "bind failed on port 5762"; PX4: "failed to set lock on file"), so a claim is an
exclusive ``flock`` that other processes (test workers) see too; the kernel drops it if the
holder dies."""


def _claim(kind: str, instance: int) -> bool:
    with _CLAIM_LOCK:
        if (kind, instance) in _CLAIMED:
            return False
        path = Path(tempfile.gettempdir()) / f"col-autopilot-{kind}-{instance}.lock"
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            return False
        _CLAIMED[(kind, instance)] = fd
        return True


def _release(kind: str, instance: int) -> None:
    with _CLAIM_LOCK:
        fd = _CLAIMED.pop((kind, instance), None)
    if fd is not None:
        os.close(fd)  # closing the descriptor drops the flock


def free_px4_instance(first: int = 0, last: int = 9) -> int:
    """The first PX4 instance whose ports (its own and the ones it sends to) are all free,
    claimed for this process until its autopilot stops."""
    for i in range(first, last + 1):
        if all(udp_port_free(p + i) for p in (*PX4_LOCAL_PORTS, PX4_OFFBOARD_PORT, PX4_GCS_PORT)) and _claim("px4", i):
            return i
    raise RuntimeError(f"no free PX4 instance in {first}..{last}: ports 14540-14590 + instance are taken")


def free_ardupilot_instance(first: int = 0, last: int = 9) -> int:
    """The first ArduCopter instance whose TCP serial ports and simulator ports are free,
    claimed for this process until its autopilot stops."""
    for i in range(first, last + 1):
        tcp = [ARDUPILOT_TCP_PORT + 10 * i + k for k in (0, 2, 3)]
        udp = [p + 10 * i for p in ARDUPILOT_SIM_PORTS]
        if all(_tcp_free(p) for p in tcp) and all(udp_port_free(p) for p in udp) and _claim("ardupilot", i):
            return i
    raise RuntimeError(f"no free ArduCopter instance in {first}..{last}")


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def px4_bin_dir(root: Path, workdir: Path) -> Path:
    """A ``bin`` folder whose ``px4-<module>`` commands run ``px4`` (links repaired if lost)."""
    source = root / "px4" / "bin"
    target = workdir / "bin"
    target.mkdir(parents=True, exist_ok=True)
    real = (source / "px4").resolve()
    for entry in source.iterdir():
        link = target / entry.name
        if link.exists() or link.is_symlink():
            continue
        lost_link = entry.is_file() and entry.stat().st_size <= 8 and entry.read_bytes().strip() == b"px4"
        link.symlink_to(real if lost_link else entry.resolve())
    return target


def _spawn(cmd: list[str], cwd: Path, env: dict[str, str], log_path: Path) -> tuple[subprocess.Popen[bytes], object]:
    log = log_path.open("wb")
    proc = subprocess.Popen(cmd, cwd=cwd, env=env, stdin=subprocess.DEVNULL, stdout=log,
                            stderr=subprocess.STDOUT, start_new_session=True)
    return proc, log


def start_px4(root: Path, workdir: Path, instance: int | None = None, speedup: float = 1.0) -> RunningAutopilot:
    """PX4 SITL with SIH (airframe 10040) in ``workdir``; the companion listens on its
    offboard link, ``udpin:127.0.0.1:14540+instance``. Armable 20-25 s after start (of its own
    time). ``speedup``: PX4_SIM_SPEED_FACTOR, its lockstep scheduler's speed against the wall
    clock (fly it with ``[companion.session] clock = "vehicle"``)."""
    inst = free_px4_instance() if instance is None else instance
    workdir.mkdir(parents=True, exist_ok=True)
    run_dir = workdir / "px4"
    run_dir.mkdir(exist_ok=True)
    bin_dir = px4_bin_dir(root, workdir)
    env = dict(os.environ, PATH=f"{bin_dir}{os.pathsep}{os.environ.get('PATH', '')}",
               PX4_SIM_MODEL="sihsim_quadx", PX4_SIMULATOR="sihsim")
    if speedup != 1.0:
        env["PX4_SIM_SPEED_FACTOR"] = f"{speedup:g}"
    log_path = workdir / "px4.log"
    cmd = [str(bin_dir / "px4"), "-d", "-i", str(inst), "-w", str(run_dir), str(root / "px4" / "etc")]
    proc, log = _spawn(cmd, workdir, env, log_path)
    return RunningAutopilot("px4", inst, proc, f"udpin:127.0.0.1:{PX4_OFFBOARD_PORT + inst}", workdir, log_path, log)


def start_ardupilot(root: Path, workdir: Path, instance: int | None = None,
                    port: int | None = None, speedup: float = 1.0) -> RunningAutopilot:
    """ArduCopter SITL (built-in quad) in ``workdir`` with a fresh eeprom, sending its first
    serial port to the companion at ``udpin:127.0.0.1:PORT`` (a free port unless given).
    Armable in GUIDED 25-45 s after start, once its EKF uses GPS. ``speedup``: its --speedup."""
    inst = free_ardupilot_instance() if instance is None else instance
    udp_port = free_udp_port() if port is None else port
    workdir.mkdir(parents=True, exist_ok=True)
    ap = root / "ardupilot"
    log_path = workdir / "arducopter.log"
    cmd = [str(ap / "arducopter"), "--model", "quad", "--speedup", f"{speedup:g}", "--defaults", str(ap / "copter.parm"),
           f"-I{inst}", "-w", "--serial0", f"udpclient:127.0.0.1:{udp_port}"]
    proc, log = _spawn(cmd, workdir, dict(os.environ), log_path)
    return RunningAutopilot("ardupilot", inst, proc, f"udpin:127.0.0.1:{udp_port}", workdir, log_path, log)


@contextlib.contextmanager
def running(kind: Kind, workdir: Path, root: Path | None = None, speedup: float = 1.0) -> Iterator[RunningAutopilot]:
    """Start ``kind`` for the block (``speedup`` times real time), stop it after (also on errors)."""
    found, why = (root, "") if root is not None else find_autopilots()
    if found is None:
        raise FileNotFoundError(why)
    ap = (start_px4(found, workdir, speedup=speedup) if kind == "px4"
          else start_ardupilot(found, workdir, speedup=speedup))
    try:
        yield ap
    finally:
        ap.stop()
