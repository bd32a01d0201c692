"""The learner in its own process, so that training can never stall the control loop.

A learner *thread* shares the GIL with control: when the OS preempts it while it holds the GIL
(a machine loaded by other processes), the control tick waits. :class:`LearnerProcess` runs the
same :class:`Learner` (the paper's loop) in a child process started with ``spawn``:

- samples: the child tails the append-only CSV that :class:`HumanDataset` writes on every
  append (:class:`CsvTail`: complete lines only, a torn last line waits for its newline);
- snapshots: the child sends plain NumPy arrays over a ``multiprocessing.Pipe`` (a socket pair)
  as length-prefixed frames; control reads them from a non-blocking socket (a partial frame
  stays buffered until complete), so it never waits, and swaps the newest in with one assignment;
- flow control: at most two snapshot frames are in flight, returned as credits when control
  reads them; a snapshot trained on new samples may use either, a merely newer one only the
  second, so a fresh snapshot never queues behind stale ones and the child never fills the pipe;
- failure: the child sends its traceback and its last good snapshot; a silent death is seen as
  the socket's end plus the exit code. Control keeps flying the last good snapshot.
"""

from __future__ import annotations

import math
import multiprocessing
import os
import pickle
import select
import signal
import struct
import threading
import time
import traceback
from dataclasses import dataclass
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

import numpy as np

from companion.config import LearnerConfig
from companion.errors import ColError, ConfigError, DatasetCorrupt
from companion.learning.dataset import DatasetView, csv_header
from companion.learning.learner import Learner, LearnerState
from companion.learning.snapshot import Normalisation, PolicySnapshot
from companion.learning.trainer import limit_torch_threads
from companion.msg.command import ACT_DIM
from companion.msg.observation import OBS_NAMES
from companion.msg.sample import Source

_HEADER = struct.Struct("!BI")  # frame kind, payload length
_SNAPSHOT, _STATE, _FINAL, _ERROR = 1, 2, 3, 4
_ACK, _STOP = b"a", b"s"  # control -> child, one byte each
MAX_IN_FLIGHT = 2  # snapshot frames sent and not yet read by control


class LearnerProcessFailed(ColError):
    """The learner process raised or died; control flies the last good snapshot."""


# -- the dataset as the child sees it ---------------------------------------------------------
class CsvTail:
    """The human dataset read from its CSV file as the file grows (a :class:`SampleSource`).

    ``poll()`` reads what was appended since the last call and keeps complete lines only. A
    complete line that cannot be read raises :class:`DatasetCorrupt`: the writer writes whole
    lines, so it is not a write in progress. Rows live in arrays that grow into new arrays, so
    a view handed out earlier stays valid.
    """

    def __init__(self, path: str | Path, obs_names: tuple[str, ...] = OBS_NAMES,
                 *, chunk_rows: int = 4096) -> None:
        self.path = Path(path)
        self._header = ",".join(csv_header(obs_names)).encode()
        self._n_cols = len(csv_header(obs_names))
        self._obs_dim = len(obs_names)
        self._chunk_rows = chunk_rows
        self._cols = {"obs": np.empty((chunk_rows, self._obs_dim), np.float32),
                      "actions": np.empty((chunk_rows, ACT_DIM), np.float32),
                      "intervention": np.zeros(chunk_rows, bool),
                      "episode": np.zeros(chunk_rows, np.int64), "step": np.zeros(chunk_rows, np.int64)}
        self._view = DatasetView(**{name: col[:0] for name, col in self._cols.items()})
        self._pending = b""
        self._lines_seen = 0  # including the header
        self._fd = os.open(self.path, os.O_RDONLY)
        self.poll()

    def close(self) -> None:
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1

    def __len__(self) -> int:
        return len(self._view)

    def view(self) -> DatasetView:
        return self._view

    def wait_for_growth(self, known: int, timeout_s: float) -> int:
        """Poll the file until it holds more than ``known`` rows or the timeout passes."""
        deadline = time.monotonic() + timeout_s
        while self.poll() <= known and time.monotonic() < deadline:
            time.sleep(min(0.002, max(0.0, deadline - time.monotonic())))
        return len(self)

    def poll(self) -> int:
        """Take in the complete lines appended since the last call; the number of rows."""
        chunks = [self._pending]
        while chunk := os.read(self._fd, 1 << 20):
            chunks.append(chunk)
        data = b"".join(chunks)
        end = data.rfind(b"\n") + 1
        self._pending = data[end:]
        lines = data[:end].split(b"\n")[:-1]
        if lines and self._lines_seen == 0:
            self._check_header(lines.pop(0))
        if lines:
            self._append(self._parse(lines))
        return len(self)

    def _check_header(self, line: bytes) -> None:
        self._lines_seen = 1
        if line != self._header:
            raise DatasetCorrupt(f"{self.path}: the header is not the dataset's "
                                 f"({self._header.decode()}); point the learner at the right file")

    def _parse(self, lines: list[bytes]) -> dict[str, np.ndarray]:
        """The lines' columns as arrays, by :class:`DatasetView`'s field names."""
        first = self._lines_seen + 1
        self._lines_seen += len(lines)
        rows = [line.decode("utf-8", "replace").split(",") for line in lines]
        for i, row in enumerate(rows):
            if len(row) != self._n_cols:
                raise DatasetCorrupt(f"{self.path}: line {first + i} has {len(row)} columns, not "
                                     f"{self._n_cols}; repair or remove that line")
        try:
            values = np.array([row[4:] for row in rows], dtype=np.float32)
            episode = np.array([row[0] for row in rows], dtype=np.int64)
            step = np.array([row[1] for row in rows], dtype=np.int64)
            intervention = np.array([Source(row[3]) is Source.INTERVENTION for row in rows], bool)
        except ValueError as exc:
            raise DatasetCorrupt(f"{self.path}: lines {first}-{first + len(rows) - 1} hold a "
                                 f"value that cannot be read ({exc}); repair that line") from exc
        if not np.all(np.isfinite(values)):
            raise DatasetCorrupt(f"{self.path}: lines {first}-{first + len(rows) - 1} hold a "
                                 "non-finite value; repair that line")
        return {"obs": values[:, :self._obs_dim], "actions": values[:, self._obs_dim:],
                "intervention": intervention, "episode": episode, "step": step}

    def _append(self, new: dict[str, np.ndarray]) -> None:
        n, m = len(self), new["obs"].shape[0]
        if n + m > self._cols["obs"].shape[0]:
            capacity = max(n + m, 2 * self._cols["obs"].shape[0]) + self._chunk_rows
            self._cols = {name: _grown(col, capacity) for name, col in self._cols.items()}
        published = {}
        for name, col in self._cols.items():
            col[n:n + m] = new[name]
            published[name] = col[:n + m]
            published[name].flags.writeable = False
        self._view = DatasetView(**published)


def _grown(old: np.ndarray, capacity: int) -> np.ndarray:
    new = np.empty((capacity, *old.shape[1:]), old.dtype)
    new[: old.shape[0]] = old
    return new


# -- what crosses the pipe --------------------------------------------------------------------
def _snapshot_payload(snap: PolicySnapshot, size_published_at_s: float) -> dict[str, Any]:
    return {"weights": [np.asarray(w) for w in snap.weights],
            "biases": [np.asarray(b) for b in snap.biases],
            "mean": np.asarray(snap.normalisation.mean), "std": np.asarray(snap.normalisation.std),
            "version": snap.version, "size": snap.dataset_size_trained,
            "size_published_at_s": size_published_at_s}


def _snapshot_from(payload: dict[str, Any]) -> PolicySnapshot:
    return PolicySnapshot(tuple(payload["weights"]), tuple(payload["biases"]),
                          Normalisation(payload["mean"], payload["std"]),
                          payload["version"], payload["size"])


def _frame(kind: int, payload: object) -> bytes:
    body = pickle.dumps(payload, protocol=5)
    return _HEADER.pack(kind, len(body)) + body


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view):]


class _FrameReader:
    """Reads whole frames from a non-blocking socket; a partial frame waits in the buffer."""

    def __init__(self, fd: int) -> None:
        self.fd = fd
        self.eof = False
        self._buf = bytearray()

    def read_available(self) -> list[tuple[int, bytes]]:
        while not self.eof:
            try:
                chunk = os.read(self.fd, 1 << 20)
            except BlockingIOError:
                break
            except OSError:  # the child's end is gone (reset)
                chunk = b""
            if not chunk:
                self.eof = True
            self._buf += chunk
        frames, pos = [], 0
        while len(self._buf) - pos >= _HEADER.size:
            kind, n = _HEADER.unpack_from(self._buf, pos)
            start = pos + _HEADER.size
            if len(self._buf) - start < n:
                break
            frames.append((kind, bytes(self._buf[start:start + n])))
            pos = start + n
        del self._buf[:pos]
        return frames


# -- the child ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class _ChildJob:
    """Everything the child needs to rebuild the parent's learner (picklable)."""

    config: LearnerConfig
    csv_path: Path
    obs_names: tuple[str, ...]
    initial: PolicySnapshot
    rng: np.random.Generator
    optimizer_state: dict[str, Any]
    idle_poll_s: float


class _ChildLink:
    """The child's end: reads credits and the stop request, sends frames (blocking is fine here)."""

    def __init__(self, conn: Connection) -> None:
        self.conn = conn
        self.fd = conn.fileno()
        self.credits = MAX_IN_FLIGHT
        self.stopping = False
        self._sent: PolicySnapshot | None = None
        self._sent_size = -1
        self._size_seen = -1
        self._size_first_at_s = math.nan

    def read_commands(self, timeout_s: float = 0.0) -> None:
        """Take credits and a stop request (or the parent's end: also stop) from the socket."""
        if not select.select([self.fd], [], [], timeout_s)[0]:
            return
        data = os.read(self.fd, 4096)
        self.credits += data.count(_ACK)
        self.stopping = self.stopping or not data or _STOP in data

    def send(self, kind: int, payload: object) -> None:
        _write_all(self.fd, _frame(kind, payload))

    def offer(self, snap: PolicySnapshot) -> None:
        """Send ``snap`` if credits allow: new samples may use the last credit, the rest not."""
        if snap.dataset_size_trained > self._size_seen:
            self._size_seen, self._size_first_at_s = snap.dataset_size_trained, time.perf_counter()
        if snap is self._sent:
            return
        fresh = snap.dataset_size_trained > self._sent_size
        if self.credits >= (1 if fresh else MAX_IN_FLIGHT):
            self.send(_SNAPSHOT, _snapshot_payload(snap, self._size_first_at_s))
            self.credits -= 1
            self._sent, self._sent_size = snap, snap.dataset_size_trained

    def last_payload(self, snap: PolicySnapshot) -> dict[str, Any]:
        return _snapshot_payload(snap, self._size_first_at_s)


def _child_main(conn: Connection, job: _ChildJob) -> None:
    """Entry point of the learner process: train until told to stop, then send the final state.

    Ends with ``os._exit`` right after its last frame: the parent already has everything, and
    tearing down torch at a low priority on a loaded machine can take seconds.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is for the parent, which stops us
    limit_torch_threads(job.config.torch_threads)
    link = _ChildLink(conn)
    learner: Learner | None = None
    try:
        tail = CsvTail(job.csv_path, job.obs_names)
        learner = Learner(job.config, tail, obs_dim=job.initial.obs_dim, initial=job.initial,
                          rng=job.rng)
        if job.optimizer_state:
            learner.trainer.load_state(job.optimizer_state)
        _lower_process_priority(job.config.thread_nice)  # after the set-up, which control awaits
        _train_until_stopped(learner, tail, link, job.idle_poll_s)
        if learner.updates > learner.latest_snapshot.version:
            learner.publish()
        link.send(_FINAL, {"snapshot": link.last_payload(learner.latest_snapshot),
                           "updates": learner.updates})
    except Exception:
        payload = {"traceback": traceback.format_exc(),
                   "snapshot": None if learner is None else link.last_payload(learner.latest_snapshot)}
        try:
            link.send(_ERROR, payload)
        except OSError:
            pass  # the parent is gone: nobody to tell
        os._exit(1)
    os._exit(0)


def _train_until_stopped(learner: Learner, tail: CsvTail, link: _ChildLink, idle_poll_s: float) -> None:
    training: bool | None = None
    while True:
        link.read_commands()
        if link.stopping:
            return
        tail.poll()
        if learner.has_work != training:
            training = learner.has_work
            link.send(_STATE, (LearnerState.TRAINING if training else LearnerState.IDLE).value)
        if training:
            learner.train_until_converged(budget=1, publish_at_end=False)
        link.offer(learner.latest_snapshot)
        if not training:
            link.read_commands(idle_poll_s)  # sleeps, but wakes at once for a credit or stop


def _lower_process_priority(nice: int) -> None:
    """Raise this process's niceness to ``nice`` (no-op where unsupported)."""
    if nice > 0 and hasattr(os, "nice"):
        try:
            os.nice(max(0, nice - os.nice(0)))
        except OSError:
            pass  # not allowed here: train at the inherited priority


# -- the control side ---------------------------------------------------------------------------
class LearnerProcess:
    """Runs the paper's loop in a child process; same interface as :class:`LearnerThread`.

    The control loop calls ``on_control_step()`` once per tick (or reads ``latest_snapshot``):
    both read whatever the child sent, without blocking, and swap the newest snapshot in with
    one assignment (also into ``learner.latest_snapshot``, so checkpoints see it). The parent's
    torch model is not trained; to train in this process later, build a new :class:`Learner`
    from ``latest_snapshot``. ``stop()`` waits for the child's final snapshot (all its updates).
    """

    def __init__(self, learner: Learner, *, idle_poll_s: float = 0.002) -> None:
        path = getattr(learner.dataset, "path", None)
        if path is None:
            raise ConfigError(
                "learner mode 'process' reads the samples from the dataset's CSV file, and this "
                "dataset has none: record to a file, or set [companion.learner] mode = \"thread\"")
        self.learner = learner
        self.csv_path = Path(path)
        self.idle_poll_s = idle_poll_s
        self.size_published_at_s = math.nan  # child's perf_counter: latest size first published
        self._latest = learner.latest_snapshot
        self._state = LearnerState.NEW
        self._error: BaseException | None = None
        self._ended = False  # final frame, error frame or end of the socket seen
        self._poll_lock = threading.Lock()
        self._process: multiprocessing.process.BaseProcess | None = None
        self._conn: Connection | None = None
        self._reader: _FrameReader | None = None

    @property
    def state(self) -> LearnerState:
        """NEW, IDLE or TRAINING (as the child last said), then STOPPED or FAILED."""
        self._poll()
        return self._state

    @property
    def error(self) -> BaseException | None:
        """Why the child failed (its traceback, or its exit code), if it did."""
        self._poll()
        return self._error

    @property
    def pid(self) -> int | None:
        return None if self._process is None else self._process.pid

    @property
    def latest_snapshot(self) -> PolicySnapshot:
        """The newest snapshot received; reads the pipe first, never waits."""
        self._poll()
        return self._latest

    def between_episodes(self) -> int:
        """Nothing to do: the child goes on training while the vehicle is repositioned."""
        return 0

    def on_control_step(self, tick_start_s: float | None = None) -> PolicySnapshot:
        """The snapshot to fly now; never waits (``tick_start_s`` is not needed: no GIL to share)."""
        return self.latest_snapshot

    def start(self) -> None:
        if self._state is not LearnerState.NEW:
            raise RuntimeError(f"learner process already {self._state.value}; make a new one")
        ctx = multiprocessing.get_context("spawn")
        parent_conn, child_conn = ctx.Pipe(duplex=True)
        dataset = self.learner.dataset
        job = _ChildJob(self.learner.config, self.csv_path,
                        tuple(getattr(dataset, "obs_names", OBS_NAMES)), self._latest,
                        self.learner.rng, self.learner.trainer.state(),
                        self.idle_poll_s)
        self._process = ctx.Process(target=_child_main, args=(child_conn, job),
                                    name="col-learner", daemon=True)
        self._process.start()
        child_conn.close()  # only the child holds its end: its death reads as end of file
        os.set_blocking(parent_conn.fileno(), False)
        self._conn, self._reader = parent_conn, _FrameReader(parent_conn.fileno())
        self._state = LearnerState.IDLE

    def stop(self, timeout_s: float = 5.0) -> LearnerState:
        """Ask the child to finish its update and send its final snapshot; reap it."""
        if self._process is None or self._conn is None:
            self._state = LearnerState.STOPPED if self._state is LearnerState.NEW else self._state
            return self._state
        deadline = time.monotonic() + timeout_s
        self._send(_STOP)
        while not self._ended and time.monotonic() < deadline:
            select.select([self._conn.fileno()], [], [], max(0.0, deadline - time.monotonic()))
            self._poll(wait_for_lock=True)
        self._reap(max(0.0, deadline - time.monotonic()))
        return self._state

    def __enter__(self) -> LearnerProcess:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -- internals ----------------------------------------------------------------------
    def _reap(self, timeout_s: float) -> None:
        assert self._process is not None and self._conn is not None
        self._process.join(timeout_s)
        if self._process.is_alive():
            self._process.terminate()
            self._process.join(1.0)
        if self._process.is_alive():
            self._process.kill()
            self._process.join()
        if not self._ended:
            self._fail(f"the learner process did not stop within the timeout (exit code "
                       f"{self._process.exitcode}); its last updates are lost")
        self._conn.close()
        self._conn = None
        if self._state is not LearnerState.FAILED:
            self._state = LearnerState.STOPPED

    def _send(self, data: bytes) -> None:
        if self._conn is None:
            return
        try:
            os.write(self._conn.fileno(), data)
        except (BlockingIOError, OSError):
            pass  # a full or closed socket: the child is stuck or gone, which _poll reports

    def _poll(self, *, wait_for_lock: bool = False) -> None:
        if self._reader is None or self._conn is None or self._ended:
            return
        if not self._poll_lock.acquire(blocking=wait_for_lock):
            return  # another thread is reading the pipe right now
        try:
            self._take(self._reader.read_available())
        finally:
            self._poll_lock.release()

    def _take(self, frames: list[tuple[int, bytes]]) -> None:
        snapshots = [body for kind, body in frames if kind == _SNAPSHOT]
        if snapshots:
            self._adopt(pickle.loads(snapshots[-1]))  # only the newest is unpickled
            self._send(_ACK * len(snapshots))
        for kind, body in frames:
            if kind == _STATE and self._state not in (LearnerState.FAILED, LearnerState.STOPPED):
                self._state = LearnerState(pickle.loads(body))
            elif kind == _FINAL:
                self._adopt(pickle.loads(body)["snapshot"])
                self._ended, self._state = True, LearnerState.STOPPED
            elif kind == _ERROR:
                payload = pickle.loads(body)
                if payload["snapshot"] is not None:
                    self._adopt(payload["snapshot"])
                self._ended = True
                self._fail("the learner process failed; control keeps flying snapshot "
                           f"v{self._latest.version}:\n{payload['traceback']}")
        assert self._reader is not None and self._process is not None
        if self._reader.eof and not self._ended:
            self._ended = True
            code = self._process.exitcode  # polls, never waits; None if not reaped yet
            self._fail(f"the learner process died (exit code {code}); control keeps flying "
                       f"snapshot v{self._latest.version}; see its log, then start a new run")

    def _adopt(self, payload: dict[str, Any]) -> None:
        snap = _snapshot_from(payload)
        if snap.version < self._latest.version:
            return
        self._latest = snap
        self.size_published_at_s = payload["size_published_at_s"]
        self.learner.adopt(snap)

    def _fail(self, message: str) -> None:
        if self._error is None:
            self._error = LearnerProcessFailed(message)
        self._state = LearnerState.FAILED
