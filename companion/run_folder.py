"""The run folder is checked before anything starts: a folder that cannot be written (read-only,
full disk, a file in the way) is a clear error before the first episode, with nothing
half-written, instead of a crash in the middle of one. A run that fails before it recorded
anything removes the folder it made, so a mistyped option leaves no empty run behind."""

from __future__ import annotations

import contextlib
import errno
import os
import shutil
from collections.abc import Iterator
from pathlib import Path

from companion.errors import ConfigError

KEPT_EMPTY_OK = frozenset({"environment.jsonl"})
"""Files a run writes before it does anything: alone (with empty files) they are not worth keeping."""

PROBE_BYTES = 1 << 16  # a checkpoint's order of size: a disk with less room fails here


def prepare_run_dir(run_dir: Path) -> None:
    """Create ``run_dir`` (and its checkpoints folder) and prove it takes a write."""
    probe = run_dir / f".write-test-{os.getpid()}"
    try:
        (run_dir / "checkpoints").mkdir(parents=True, exist_ok=True)
        with probe.open("wb") as f:
            f.write(bytes(PROBE_BYTES))
            f.flush()
            os.fsync(f.fileno())
    except OSError as exc:
        full = exc.errno in (errno.ENOSPC, errno.EDQUOT)
        raise ConfigError(
            f"cannot write to the run folder {run_dir}: {exc.strerror or exc}; "
            + ("free some disk space or " if full else "")
            + "choose a writable --run-dir (nothing was started or written)"
        ) from None
    finally:
        try:
            probe.unlink()
        except OSError:
            pass


def first_missing(path: Path) -> Path | None:
    """The outermost folder of ``path`` that does not exist yet (what creating it would make)."""
    missing = None
    for folder in (path, *path.parents):
        if folder.exists():
            break
        missing = folder
    return missing


def holds_nothing(folder: Path) -> bool:
    """True when ``folder`` has only empty files, empty folders and the environment record."""
    for item in folder.rglob("*"):
        if item.is_file() and item.name not in KEPT_EMPTY_OK and item.stat().st_size > 0:
            return False
        if item.is_symlink() or not (item.is_file() or item.is_dir()):
            return False
    return True


@contextlib.contextmanager
def removed_if_unused(run_dir: Path) -> Iterator[None]:
    """On an error, remove the folders this run is about to create if nothing was recorded in
    them (no episode, no telemetry); a folder that existed before is never touched."""
    made = first_missing(run_dir)
    try:
        yield
    except BaseException:
        if made is not None and made.is_dir() and holds_nothing(made):
            shutil.rmtree(made, ignore_errors=True)
        raise
