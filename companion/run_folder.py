"""The run folder is checked before anything starts: a folder that cannot be written (read-only,
full disk, a file in the way) is a clear error before the first episode, with nothing
half-written, instead of a crash in the middle of one."""

from __future__ import annotations

import errno
import os
from pathlib import Path

from companion.errors import ConfigError

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
