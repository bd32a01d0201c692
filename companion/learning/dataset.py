"""The human dataset: the paper's append-only CSV of the person's observation/action pairs.

File: one header line, then one line per sample::

    episode,step,time_s,source,<the observation names>,roll,pitch,yaw,throttle

``source`` is ``demonstration`` or ``intervention``. Every append is one ``os.write`` of whole
lines on an ``O_APPEND`` descriptor, so a crash of the process loses at most the rows of the
call in flight (``sync()`` also survives power loss). Loading tolerates a torn last line and
reports what it skipped; opening an existing file resumes it.

Discarding an episode (a demonstration nobody flew, say) deletes nothing: its rows stay in the
CSV and a line saying which episode, how many rows, when and why is appended to
``<name>.discarded.jsonl`` beside it; the in-memory set drops them, and so does every later
opening of the file (:func:`discarded_episodes`).

Training never reads the file: rows also go to in-memory arrays that grow in chunks. Rows are
written once and never moved or changed afterwards; ``view()`` hands out read-only slices up to
the length published at that moment, so the learner reads without locks while appends go on.
"""

from __future__ import annotations

import json
import logging
import os
import threading
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from companion.errors import DatasetCorrupt
from companion.msg.command import ACT_DIM, ACTION_NAMES
from companion.msg.observation import OBS_NAMES
from companion.msg.sample import Sample, Source

log = logging.getLogger(__name__)

META_COLUMNS: tuple[str, ...] = ("episode", "step", "time_s", "source")
DISCARDS_SUFFIX = ".discarded.jsonl"


def discarded_episodes(csv_path: str | Path) -> set[int]:
    """Episodes of a dataset file taken out of training (its audit file; unreadable lines are
    reported and skipped, so a torn last line after a crash costs nothing)."""
    p = Path(csv_path)
    audit = p.with_name(p.stem + DISCARDS_SUFFIX)
    if not audit.exists():
        return set()
    out: set[int] = set()
    for i, line in enumerate(audit.read_text().splitlines(), start=1):
        try:
            out.add(int(json.loads(line)["episode"]))
        except (ValueError, KeyError, TypeError):
            log.warning("%s: line %d unreadable, skipped", audit, i)
    return out


@dataclass(frozen=True)
class DatasetView:
    """Read-only rows ``[0, n)`` as they were when the view was taken."""

    obs: np.ndarray
    actions: np.ndarray
    intervention: np.ndarray | None = None
    """Per row: recorded while the person intervened (None where the source is not kept)."""
    episode: np.ndarray | None = None
    """Per row: the episode it was recorded in (None where not kept)."""
    step: np.ndarray | None = None
    """Per row: its control step within the episode (None where not kept)."""

    def __len__(self) -> int:
        return int(self.obs.shape[0])


@dataclass(frozen=True)
class LoadReport:
    """What loading a file kept and skipped (a torn tail is normal after a crash)."""

    rows: int
    skipped_rows: int = 0
    skipped_bytes: int = 0
    good_bytes: int = 0
    problems: tuple[str, ...] = ()


@dataclass(frozen=True)
class LoadedRows:
    """Every column of a loaded file as arrays."""

    episode: np.ndarray
    step: np.ndarray
    time_s: np.ndarray
    source: tuple[Source, ...]
    obs: np.ndarray
    actions: np.ndarray
    report: LoadReport = field(default_factory=lambda: LoadReport(0))


def csv_header(obs_names: Sequence[str] = OBS_NAMES) -> tuple[str, ...]:
    return (*META_COLUMNS, *obs_names, *ACTION_NAMES)


def format_row(sample: Sample) -> str:
    """One CSV line; ``.9g`` round-trips float32 exactly."""
    nums = ",".join(f"{v:.9g}" for v in (*sample.obs.tolist(), *sample.action.tolist()))
    return f"{sample.episode},{sample.step},{sample.time_s:.6f},{sample.source.value},{nums}\n"


def _parse_row(line: str, n_cols: int, obs_dim: int) -> tuple[int, int, float, Source, list[float]]:
    parts = line.split(",")
    if len(parts) != n_cols:
        raise ValueError(f"{len(parts)} columns instead of {n_cols}")
    values = [float(p) for p in parts[4:]]
    sample = Sample(int(parts[0]), int(parts[1]), float(parts[2]), Source(parts[3]),
                    np.asarray(values[:obs_dim]), np.asarray(values[obs_dim:]))
    return sample.episode, sample.step, sample.time_s, sample.source, values


def _check_header(first: str, expected: tuple[str, ...], path: Path) -> None:
    found = tuple(first.strip().split(","))
    if found == expected:
        return
    for i, (f, e) in enumerate(zip(found, expected, strict=False)):
        if f != e:
            raise DatasetCorrupt(
                f"{path}: header column {i} is {f!r}, expected {e!r} (expected header: "
                f"{','.join(expected)}); use another file or convert this one"
            )
    raise DatasetCorrupt(
        f"{path}: header has {len(found)} columns, expected {len(expected)} "
        f"({','.join(expected)}); use another file or convert this one"
    )


def load_csv(path: str | Path, obs_names: Sequence[str] = OBS_NAMES) -> LoadedRows:
    """Read a dataset file; skip (and report) a torn or unreadable last line.

    Raises DatasetCorrupt for a wrong header or an unreadable row before the last one.
    """
    p = Path(path)
    data = p.read_bytes()
    expected = csv_header(obs_names)
    head_end = data.find(b"\n")
    if head_end < 0:
        return _torn_header(data, expected, p)
    _check_header(data[:head_end].decode("utf-8", "replace"), expected, p)
    return _parse_body(data, head_end + 1, expected, len(obs_names), p)


def _torn_header(data: bytes, expected: tuple[str, ...], p: Path) -> LoadedRows:
    """A file cut inside its header line (crash at creation) holds no rows: accept it as empty."""
    if not (",".join(expected) + "\n").encode().startswith(data):
        raise DatasetCorrupt(f"{p}: does not start with the dataset header {','.join(expected)}")
    problems = (f"torn header ({len(data)} bytes) ignored",) if data else ()
    return _to_arrays([], len(expected) - len(META_COLUMNS) - ACT_DIM,
                      LoadReport(0, 0, len(data), 0, problems))


def _parse_body(data: bytes, start: int, expected: tuple[str, ...], obs_dim: int, p: Path) -> LoadedRows:
    lines = data[start:].split(b"\n")
    tail = lines.pop()  # bytes after the last newline: a torn line, or b"" when clean
    rows: list[tuple[int, int, float, Source, list[float]]] = []
    good_bytes, problems, skipped = start, [], 0
    for i, raw in enumerate(lines):
        try:
            rows.append(_parse_row(raw.decode("utf-8"), len(expected), obs_dim))
        except (ValueError, UnicodeDecodeError) as exc:
            if i < len(lines) - 1 or tail:
                raise DatasetCorrupt(
                    f"{p}: line {i + 2} is unreadable ({exc}); it is not the last line, so this is "
                    "not a crash: repair or remove that line"
                ) from exc
            problems.append(f"last line {i + 2} unreadable ({exc}); skipped")
            skipped += 1
            continue
        good_bytes += len(raw) + 1
    if tail:
        problems.append(f"torn last line ({len(tail)} bytes, no newline); skipped")
        skipped += 1
    report = LoadReport(len(rows), skipped, len(data) - good_bytes, good_bytes, tuple(problems))
    for problem in problems:
        log.warning("%s: %s", p, problem)
    return _to_arrays(rows, obs_dim, report)


def _to_arrays(rows: list, obs_dim: int, report: LoadReport) -> LoadedRows:
    values = np.array([r[4] for r in rows], dtype=np.float32).reshape(len(rows), obs_dim + ACT_DIM)
    return LoadedRows(
        episode=np.array([r[0] for r in rows], dtype=np.int64),
        step=np.array([r[1] for r in rows], dtype=np.int64),
        time_s=np.array([r[2] for r in rows], dtype=np.float64),
        source=tuple(r[3] for r in rows),
        obs=values[:, :obs_dim].copy(),
        actions=values[:, obs_dim:].copy(),
        report=report,
    )


ROW_ARRAYS: tuple[str, ...] = ("obs", "actions", "intervention", "episode", "step")
"""The in-memory columns, in :class:`DatasetView`'s field order."""


class _Rows:
    """Arrays that grow in chunks; rows below ``n`` are never written again."""

    def __init__(self, obs_dim: int, chunk_rows: int) -> None:
        self.chunk_rows = chunk_rows
        self.obs = np.empty((chunk_rows, obs_dim), np.float32)
        self.actions = np.empty((chunk_rows, ACT_DIM), np.float32)
        self.intervention = np.zeros(chunk_rows, bool)
        self.episode = np.zeros(chunk_rows, np.int64)
        self.step = np.zeros(chunk_rows, np.int64)

    def ensure(self, n_rows: int) -> None:
        """Make room; growing copies into *new* arrays, so existing views stay valid."""
        if n_rows <= self.obs.shape[0]:
            return
        capacity = max(n_rows, 2 * self.obs.shape[0]) + self.chunk_rows
        for name in ROW_ARRAYS:
            old = getattr(self, name)
            new = np.zeros((capacity, *old.shape[1:]), old.dtype)
            new[: old.shape[0]] = old
            setattr(self, name, new)


class HumanDataset:
    """The person's samples: an append-only CSV file plus in-memory arrays for training.

    ``path=None`` keeps the samples in memory only. Thread-safe: appends are serialised by a
    lock; ``view()`` and ``len()`` never take it.
    """

    def __init__(self, path: str | Path | None, obs_names: Sequence[str] = OBS_NAMES,
                 *, chunk_rows: int = 4096) -> None:
        self.obs_names = tuple(obs_names)
        self.path = None if path is None else Path(path)
        self._rows = _Rows(len(self.obs_names), chunk_rows)
        self._publish(0)
        self._cond = threading.Condition(threading.Lock())
        self.counts = {s: 0 for s in Source}
        self.last_episode = -1
        self.load_report = LoadReport(0)
        self.discarded: set[int] = set()
        self._fd = -1 if self.path is None else self._open_file(self.path)

    # -- file ---------------------------------------------------------------------------
    def _open_file(self, p: Path) -> int:
        """Create with a header, or resume: keep good rows, cut a torn tail, then append."""
        p.parent.mkdir(parents=True, exist_ok=True)
        if p.exists() and p.stat().st_size > 0:
            loaded = load_csv(p, self.obs_names)
            self.load_report = loaded.report
            self._take(loaded)
            if loaded.report.skipped_bytes:
                log.warning("%s: cutting %d unreadable bytes at the end before appending",
                            p, loaded.report.skipped_bytes)
                os.truncate(p, loaded.report.good_bytes)
        fd = os.open(p, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        if os.fstat(fd).st_size == 0:
            _write_all(fd, (",".join(csv_header(self.obs_names)) + "\n").encode())
        return fd

    def _take(self, loaded: LoadedRows) -> None:
        self.last_episode = int(loaded.episode.max()) if loaded.episode.size else -1
        assert self.path is not None
        self.discarded = discarded_episodes(self.path)
        keep = ~np.isin(loaded.episode, sorted(self.discarded))
        n = int(keep.sum())
        self._rows.ensure(n)
        self._rows.obs[:n] = loaded.obs[keep]
        self._rows.actions[:n] = loaded.actions[keep]
        sources = [s for s, k in zip(loaded.source, keep, strict=True) if k]
        self._rows.intervention[:n] = [s is Source.INTERVENTION for s in sources]
        self._rows.episode[:n] = loaded.episode[keep]
        self._rows.step[:n] = loaded.step[keep]
        for s in sources:
            self.counts[s] += 1
        self._publish(n)

    def sync(self) -> None:
        """fsync the file (e.g. at the end of an episode) so rows survive a power loss too."""
        if self._fd >= 0:
            os.fsync(self._fd)

    def close(self) -> None:
        with self._cond:
            if self._fd >= 0:
                os.fsync(self._fd)
                os.close(self._fd)
                self._fd = -1

    def __enter__(self) -> HumanDataset:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- writing ------------------------------------------------------------------------
    def append(self, sample: Sample) -> int:
        """Write one sample (file first, then memory); returns the new number of samples."""
        return self.extend((sample,))

    def extend(self, samples: Iterable[Sample]) -> int:
        """Write samples with a single ``os.write``: all of them reach the file or none."""
        batch = list(samples)
        for s in batch:
            if s.obs.shape != (len(self.obs_names),):
                raise ValueError(f"observation has {s.obs.shape[0]} values, the dataset {len(self.obs_names)}")
        lines = "".join(format_row(s) for s in batch).encode() if self.path is not None else b""
        with self._cond:
            if self.path is not None:
                if self._fd < 0:
                    raise ValueError(f"dataset {self.path} is closed; open it again to append")
                _write_all(self._fd, lines)
            n = len(self._published)
            self._rows.ensure(n + len(batch))
            for i, s in enumerate(batch, start=n):
                self._rows.obs[i] = s.obs
                self._rows.actions[i] = s.action
                self._rows.intervention[i] = s.source is Source.INTERVENTION
                self._rows.episode[i], self._rows.step[i] = s.episode, s.step
                self.counts[s.source] += 1
                self.last_episode = max(self.last_episode, s.episode)
            self._publish(n + len(batch))
            self._cond.notify_all()
            return n + len(batch)

    def discard_episode(self, episode: int, reason: str) -> int:
        """Take ``episode``'s rows out of training, with an audit line; returns how many.

        Only the newest episode in memory can go (its rows are the last ones): ValueError for
        any other, or for one already discarded. Views taken before keep their rows."""
        with self._cond:
            n = len(self._published)
            first = n
            while first > 0 and self._rows.episode[first - 1] == episode:
                first -= 1
            if episode in self.discarded:
                raise ValueError(f"episode {episode} was discarded already")
            if first == n and episode <= self.last_episode:
                raise ValueError(f"episode {episode} is not the dataset's last episode ({self.last_episode}); "
                                 "only the last one can be discarded")
            if self.path is not None:
                line = {"episode": episode, "rows": n - first, "reason": reason,
                        "time": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
                with self.discards_path(self.path).open("a") as f:
                    f.write(json.dumps(line) + "\n")
                    f.flush()
                    os.fsync(f.fileno())
            self._keep_first(first)
            self.discarded.add(episode)
            log.warning("discarded episode %d (%d samples) from training: %s", episode, n - first, reason)
            return n - first

    def _keep_first(self, n: int) -> None:
        """Publish rows ``[0, n)`` in new arrays: rows past ``n`` in old views are never rewritten."""
        old = self._rows
        fresh = _Rows(old.obs.shape[1], old.chunk_rows)
        fresh.ensure(n)
        for name in ROW_ARRAYS:
            getattr(fresh, name)[:n] = getattr(old, name)[:n]
        for i in range(n, len(self._published)):
            self.counts[Source.INTERVENTION if old.intervention[i] else Source.DEMONSTRATION] -= 1
        self._rows = fresh
        self._publish(n)

    @staticmethod
    def discards_path(path: Path) -> Path:
        return path.with_name(path.stem + DISCARDS_SUFFIX)

    def _publish(self, n: int) -> None:
        arrays = [getattr(self._rows, name)[:n] for name in ROW_ARRAYS]
        for array in arrays:
            array.flags.writeable = False
        self._published = DatasetView(*arrays)  # one assignment: readers see old or new

    # -- reading ------------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self._published)

    def view(self) -> DatasetView:
        """The rows published so far, read-only; later appends do not change it."""
        return self._published

    def wait_for_growth(self, known: int, timeout_s: float) -> int:
        """Block until more than ``known`` samples exist or the timeout passes; the new length."""
        with self._cond:
            self._cond.wait_for(lambda: len(self._published) > known, timeout=timeout_s)
            return len(self._published)


def _write_all(fd: int, data: bytes) -> None:
    """os.write may write less than asked (signals, full disks): finish or raise."""
    view = memoryview(data)
    while view:
        written = os.write(fd, view)
        view = view[written:]
