"""export_commit: a results script's library is one commit as committed, kept once made."""

from __future__ import annotations

import subprocess
from pathlib import Path

from colcommon.code_export import export_commit


def git(repo: Path, *args: str) -> str:
    return subprocess.run(["git", *args], cwd=repo, capture_output=True, text=True, check=True).stdout.strip()


def test_the_export_is_the_commit_not_the_working_tree_and_is_kept(tmp_path: Path) -> None:
    repo = tmp_path / "repo"
    repo.mkdir()
    git(repo, "init", "-q")
    (repo / "lib.py").write_text("VERSION = 1\n")
    git(repo, "add", "lib.py")
    git(repo, "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-q", "-m", "one")
    first = git(repo, "rev-parse", "HEAD")
    (repo / "lib.py").write_text("VERSION = 2\n")  # edited, not committed
    dest = tmp_path / "export"
    assert export_commit(repo, dest) == (first, True)
    assert (dest / "lib.py").read_text() == "VERSION = 1\n"
    assert (dest / "COMMIT").read_text() == first + "\n"
    git(repo, "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-q", "-am", "two")
    assert export_commit(repo, dest) == (first, False)  # a later call keeps the first export
    assert (dest / "lib.py").read_text() == "VERSION = 1\n"
    other = tmp_path / "at-first"
    assert export_commit(repo, other, first[:7]) == (first, True)  # a named commit, resolved in full
