"""Starting the SITL as a process: a start that fails or is interrupted leaves no SITL behind."""

from __future__ import annotations

import subprocess
import time

import pytest

from companion import simulator
from companion.errors import SimulatorError
from tests.conftest import free_port

pytestmark = pytest.mark.realtime  # flies in real time: a higher priority where allowed


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


def test_a_killed_parent_leaves_no_sitl_behind(tmp_path) -> None:  # type: ignore[no-untyped-def]
    import os
    import signal
    import subprocess
    import sys
    import time

    script = (
        "import sys, time\n"
        "from companion.simulator import start_sitl\n"
        f"s = start_sitl({free_port()}, clock='realtime', camera=False)\n"
        "print(s.proc.pid, flush=True)\n"
        "time.sleep(60)\n"
    )
    parent = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True,
                              cwd=os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    try:
        sitl_pid = int(parent.stdout.readline())  # type: ignore[union-attr]
        os.kill(parent.pid, signal.SIGKILL)  # no cleanup code of the parent runs
        parent.wait(5)
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            try:
                os.kill(sitl_pid, 0)
            except ProcessLookupError:
                return
            time.sleep(0.1)
        os.kill(sitl_pid, signal.SIGKILL)
        raise AssertionError("the SITL outlived the process that started it")
    finally:
        if parent.poll() is None:
            parent.kill()


def test_the_sitl_output_is_drained_after_ready() -> None:
    from companion.simulator import start_sitl

    sitl = start_sitl(free_port(), clock="realtime", camera=False, extra_args=["--verbose"])
    sitl.stop()
    deadline = time.monotonic() + 5
    while not any('"frames"' in line for line in sitl.tail) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert any('"frames"' in line for line in sitl.tail)  # the exit summary reached the tail


def test_a_lockstep_sitl_waiting_for_an_answer_stops_at_once(tmp_path) -> None:  # type: ignore[no-untyped-def]
    """SIGTERM while the SITL waits (10 s) for a lockstep answer: it exits cleanly at once.
    Python retries an interrupted select() for its whole timeout; without a wake-up the
    SITL outlived stop()'s grace and was killed, 5 s per experiment run."""
    from companion.simulator import start_sitl
    from tests.mav_client import MavTestClient

    config = tmp_path / "slow_lockstep.toml"
    config.write_text("[sitl.clock]\nlockstep_timeout_s = 10.0\n")
    client = MavTestClient()
    sitl = start_sitl(client.port, clock="lockstep", config=config, camera=False)
    try:
        last = client.wait_for(lambda m: m.get_type() == "SYSTEM_TIME", timeout_s=10.0)
        deadline = time.monotonic() + 1.0
        while time.monotonic() < deadline:  # answer the newest frame: lockstep attaches
            client.body_velocity(0.0, echo_ms=last.time_boot_ms)
            markers = [m for m in client.pump(0.15) if m.get_type() == "SYSTEM_TIME"]
            last = markers[-1] if markers else last
        time.sleep(0.5)  # then silence: the SITL waits for an answer to its newest frame
        assert not [m for m in client.pump(0.3) if m.get_type() == "SYSTEM_TIME"]
        started = time.monotonic()
        sitl.stop()
        assert time.monotonic() - started < 2.0
        assert sitl.proc.returncode == 0  # it exited by itself, not killed
    finally:
        sitl.stop()
        client.close()


def test_a_sitl_that_ignores_sigterm_is_killed_and_the_stop_returns() -> None:
    import sys

    proc = subprocess.Popen([sys.executable, "-c", "import signal, time\nsignal.signal(signal.SIGTERM, signal.SIG_IGN)\n"
                             "print('ready', flush=True)\ntime.sleep(60)"], stdout=subprocess.PIPE)
    assert proc.stdout is not None and proc.stdout.readline() == b"ready\n"
    simulator.SitlProcess(proc, {}).stop(timeout_s=0.2)
    assert proc.returncode is not None and proc.returncode < 0  # killed, not ended by itself


class _Unreaped:
    """A process that never exits: what a stop meets on a machine too busy to run a killed process's exit."""

    pid = 4242
    stdout = stderr = None
    returncode = None

    def __init__(self) -> None:
        self.signals: list[str] = []

    def poll(self) -> None:
        return None

    def terminate(self) -> None:
        self.signals.append("TERM")

    def kill(self) -> None:
        self.signals.append("KILL")

    def wait(self, timeout: float | None = None) -> int:
        raise subprocess.TimeoutExpired("sitl", timeout or 0.0)


def test_a_stop_that_cannot_reap_the_sitl_warns_and_does_not_raise(monkeypatch: pytest.MonkeyPatch,
                                                                    caplog: pytest.LogCaptureFixture) -> None:
    monkeypatch.setattr(simulator, "KILL_REAP_S", 0.01)
    proc = _Unreaped()
    simulator.SitlProcess(proc, {}).stop(timeout_s=0.01)  # type: ignore[arg-type]
    assert proc.signals == ["TERM", "KILL"]
    assert "left to the kernel" in caplog.text
