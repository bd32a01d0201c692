"""Starting the SITL as a process: a start that fails or is interrupted leaves no SITL behind."""

from __future__ import annotations

import subprocess

import pytest

from companion import simulator
from companion.errors import SimulatorError
from tests.conftest import free_port


@pytest.fixture()
def started(monkeypatch: pytest.MonkeyPatch) -> list[subprocess.Popen[bytes]]:
    """Every process start_sitl launches."""
    procs: list[subprocess.Popen[bytes]] = []
    real_popen = subprocess.Popen

    def recording_popen(*args, **kwargs):  # type: ignore[no-untyped-def]
        proc = real_popen(*args, **kwargs)
        procs.append(proc)
        return proc

    monkeypatch.setattr(simulator.subprocess, "Popen", recording_popen)
    return procs


def test_too_slow_a_start_times_out_and_stops_the_process(started: list[subprocess.Popen[bytes]]) -> None:
    with pytest.raises(SimulatorError, match="did not report READY within"):
        simulator.start_sitl(free_port(), timeout_s=0.05)
    assert len(started) == 1 and started[0].poll() is not None


def test_ctrl_c_while_starting_leaves_no_sitl_running(started: list[subprocess.Popen[bytes]],
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    def interrupted(pid: int, nice: int) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(simulator, "_lower_priority", interrupted)
    with pytest.raises(KeyboardInterrupt):
        simulator.start_sitl(free_port())
    assert len(started) == 1 and started[0].poll() is not None
