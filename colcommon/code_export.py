"""One commit's library for a results script: the repository as committed, exported clean, so a
long run uses that commit whatever the working tree holds meanwhile."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

COMMIT_FILE = "COMMIT"


def export_commit(repo: Path, dest: Path, commit: str = "HEAD") -> tuple[str, bool]:
    """``dest``: ``repo`` at ``commit`` (``git archive``), its full hash in ``dest/COMMIT``.
    Returns ``(hash, made)``. An export already there is kept, ``made`` False: a later session
    continues with the commit the first runs used."""
    marker = dest / COMMIT_FILE
    if marker.exists():
        return marker.read_text().strip(), False
    shutil.rmtree(dest, ignore_errors=True)  # an interrupted export starts over
    dest.mkdir(parents=True)
    full = subprocess.run(["git", "rev-parse", commit], cwd=repo, capture_output=True, text=True,
                          check=True).stdout.strip()
    archive = subprocess.run(["git", "archive", full], cwd=repo, capture_output=True, check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(dest)], input=archive, check=True)
    marker.write_text(full + "\n")
    return full, True
