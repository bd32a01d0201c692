"""How `make test` schedules tests. It runs two pytest-xdist workers and relies on ``--dist loadgroup`` to keep the
real-time real-autopilot tests (one module fixture flying PX4 and ArduCopter) and the CPU-bound
trial reruns on one worker. pytest 9.2 with xdist 3.8 silently dropped the groups (xdist renames
``item._nodeid``, pytest 9.2 reads ``item._id``): both workers then started PX4 instance 0 and
ArduCopter instance 0 at once. This checks the installed pair still honours a group."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("xdist")

GROUPED = """
import pytest
pytestmark = pytest.mark.xdist_group("together")

@pytest.mark.parametrize("k", range(4))
def test_grouped(k):
    pass
"""
LOOSE = """
import pytest

@pytest.mark.parametrize("k", range(4))
def test_loose(k):
    pass
"""


def test_tests_of_one_xdist_group_run_on_one_worker(tmp_path: Path) -> None:
    (tmp_path / "test_grouped.py").write_text(GROUPED)
    (tmp_path / "test_loose.py").write_text(LOOSE)
    out = subprocess.run([sys.executable, "-m", "pytest", "-p", "no:cacheprovider", "-n", "2", "--dist", "loadgroup",
                          "-v", "-o", "addopts=", str(tmp_path)],
                         capture_output=True, text=True, timeout=240, cwd=tmp_path).stdout
    workers = set(re.findall(r"\[(gw\d)\][^\n]*PASSED[^\n]*test_grouped", out))
    assert len(re.findall(r"PASSED[^\n]*test_grouped", out)) == 4, out
    assert len(workers) == 1, out


@pytest.mark.realtime
def test_a_realtime_test_and_what_it_starts_run_at_the_higher_priority() -> None:
    """At load ~10 a real-time SITL sharing the CPU evenly falls behind its clock."""
    from tests.conftest import REALTIME_NICE

    if os.geteuid() != 0:
        pytest.skip("only root may raise a priority; the test then runs at the default one")
    child = subprocess.run([sys.executable, "-c", "import os; print(os.getpriority(os.PRIO_PROCESS, 0))"],
                           capture_output=True, text=True, timeout=60)
    assert os.getpriority(os.PRIO_PROCESS, 0) == REALTIME_NICE
    assert int(child.stdout) == REALTIME_NICE


def test_other_tests_keep_the_priority_the_suite_started_with() -> None:
    from tests.conftest import STARTING_NICE

    assert os.getpriority(os.PRIO_PROCESS, 0) == STARTING_NICE


def test_grouped_tests_are_handed_out_first_in_their_collection_order(tmp_path: Path) -> None:
    (tmp_path / "test_a_loose.py").write_text(LOOSE)
    (tmp_path / "test_b_grouped.py").write_text(GROUPED)
    out = subprocess.run([sys.executable, "-m", "pytest", "-p", "no:cacheprovider", "--collect-only", "-q",
                          "-o", "addopts=", "--rootdir", str(tmp_path), "-c", os.devnull,
                          "-p", "tests.conftest", str(tmp_path)],
                         capture_output=True, text=True, timeout=240, cwd=Path(__file__).resolve().parents[1]).stdout
    names = re.findall(r"test_(grouped|loose)\[(\d)\]", out)
    assert names == [("grouped", k) for k in "0123"] + [("loose", k) for k in "0123"], out
