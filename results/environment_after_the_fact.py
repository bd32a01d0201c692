"""Write ``environment.jsonl`` into committed results folders made before runs recorded it.

Usage (from the repository's root, with the CPU's own kernels, as those runs had):

    COL_NUMERIC=native .venv/bin/python results/environment_after_the_fact.py FOLDER...

or, for results made under the project's pinned numeric profile (the default since it exists),

    .venv/bin/python results/environment_after_the_fact.py --pinned FOLDER...

which re-executes itself with that profile first. Each record is this machine's environment now, marked ``recorded_after_the_run``: the same
development machine kind made those results with the CPU's own kernels (OpenBLAS chose its
SkylakeX kernels there), but the library versions of the original runs were not written down.
``commit`` is the last commit that changed the folder.
"""

from __future__ import annotations

import json
import subprocess
import sys
from datetime import UTC, datetime
from pathlib import Path

from colcommon.numeric_env import RECORDS_NAME, ensure_pinned, record

NOTE = ("recorded after the run, from the same machine kind with the CPU's own kernels; the versions "
        "of the original run were not recorded (these are the versions of constraints.txt)")
PINNED_NOTE = ("recorded after the run, from the same machine kind under the pinned profile the run had; "
               "the run's steps recorded no environment of their own (these are the versions of constraints.txt)")


def last_commit(folder: Path) -> str:
    return subprocess.run(["git", "log", "-1", "--format=%H", "--", str(folder)], capture_output=True,
                          text=True, check=True).stdout.strip()


def main(folders: list[str], note: str = NOTE) -> None:
    import torch  # noqa: F401  (loaded, so that its CPU capability is recorded too)
    for name in folders:
        folder = Path(name)
        path = folder / RECORDS_NAME
        if path.exists():
            print(f"{path}: already has a record, left alone", file=sys.stderr)
            continue
        line = {**record(), "recorded_after_the_run": True, "note": note, "commit": last_commit(folder),
                "recorded_utc": datetime.now(UTC).isoformat(timespec="seconds")}
        path.write_text(json.dumps(line, sort_keys=True) + "\n")
        print(path)


if __name__ == "__main__":
    if sys.argv[1:2] == ["--pinned"]:
        why = ensure_pinned(sys.argv)
        if why is not None:
            sys.exit(f"the pinned profile cannot be applied here: {why}")
        main(sys.argv[2:], PINNED_NOTE)
    else:
        main(sys.argv[1:])
