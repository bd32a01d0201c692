"""Killed processes: SIGKILL the companion mid-episode (the SITL holds, then lands; every flushed
sample loads; the same --run-dir continues), SIGKILL the SITL (the companion says so, keeps its
data and exits non-zero), and an unwritable run folder (a clear error before the first episode)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from companion.simulator import SimulatorClient, start_sitl
from companion.testing.kill import ColRun, children, samples_lost, sigkill, wait_rows
from tests.conftest import free_port, wait_until

pytestmark = pytest.mark.e2e

COM_OF_LOSS_T = 1.0  # the SITL's default (sitl.autopilot.offboard_loss_hold_s)


def _records(run_dir: Path) -> list[dict]:
    return [json.loads(x) for x in (run_dir / "episodes.jsonl").read_text().splitlines() if x.strip()]


def test_sigkill_the_companion_mid_episode(tmp_path: Path) -> None:
    port = free_port()
    sitl = start_sitl(port, clock="lockstep")
    sim = SimulatorClient("127.0.0.1", sitl.control_port)
    run_dir = tmp_path / "run"
    args = ["--connect", f"udpin:127.0.0.1:{port}", "--simulator", f"127.0.0.1:{sitl.control_port}", "--pilot", "expert",
            "--condition", "demo", "--no-learn", "--lockstep", "--run-dir", str(run_dir)]
    try:
        col = ColRun.start([*args, "--episodes", "3"])
        try:
            assert wait_rows(run_dir / "human.csv", 30, 120, col.proc), col.stderr[-5:]
            sigkill(col.proc.pid)
            col.proc.wait(10)
        finally:
            col.stop()
        assert wait_until(lambda: sim.truth()["mode"] == "AUTO.LOITER", 30.0)
        t = sim.truth()
        assert t["failsafe_since_s"] - t["last_setpoint_s"] <= COM_OF_LOSS_T + 0.1
        assert wait_until(lambda: sim.truth()["landed"], 60.0)
        assert samples_lost(run_dir / "human.csv") == 0
        before = (run_dir / "human.csv").read_bytes()
        done = ColRun.start([*args, "--episodes", "1"])
        assert done.proc.wait(180) == 0, done.stderr[-5:]
        after = (run_dir / "human.csv").read_bytes()
        assert after.startswith(before.rsplit(b"\n", 1)[0]) and len(after) > len(before)  # continued, not restarted
        assert _records(run_dir)[-1]["episode"] >= 1
    finally:
        sim.close()
        sitl.stop()


def test_sigkill_the_sitl_mid_episode(tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    col = ColRun.start(["--pilot", "expert", "--episodes", "3", "--no-learn", "--run-dir", str(run_dir)])
    try:
        assert wait_rows(run_dir / "human.csv", 30, 120, col.proc), col.stderr[-5:]
        sitl_pids = children(col.proc.pid)
        assert len(sitl_pids) == 1
        killed_at = sigkill(sitl_pids[0])
        code = col.proc.wait(120)
    finally:
        col.stop()
    # said after the kill (at load ~11 a starved SITL was also silent for 1.5 s earlier, and the
    # link said so then too: that earlier loss is not the one this test is about). How soon is
    # the link's logic on its own clock
    # (tests/link/test_link.py::test_the_link_is_lost_after_link_lost_s_of_silence_on_its_clock),
    # not a wall-clock bound that a loaded machine breaks
    said = col.first("link lost", after=killed_at)
    assert said is not None
    assert code not in (0, None)
    assert any("SITL started for this run was killed" in line for _, line in col.stderr)
    assert samples_lost(run_dir / "human.csv") == 0 and (run_dir / "episodes.jsonl").exists()


@pytest.mark.parametrize("where", ["/sys/fs", "/sys/fs/col-run", "file"], ids=["read-only", "cannot-create", "file-in-the-way"])
def test_an_unwritable_run_folder_is_a_clear_error_before_anything_starts(tmp_path: Path, where: str) -> None:
    if where == "file":
        (tmp_path / "f").write_text("x")
        where = str(tmp_path / "f" / "run")
    if where.startswith("/sys") and not Path("/sys/fs").is_dir():
        pytest.skip("no /sys here")
    col = ColRun.start(["--pilot", "expert", "--episodes", "1", "--run-dir", where])
    code = col.proc.wait(60)  # only a hang fails here: no SITL was started to wait for
    assert code == 2 and any("cannot write to the run folder" in line for _, line in col.stderr), col.stderr
    assert children(col.proc.pid) == []


def test_a_full_disk_is_reported_with_what_to_do(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import errno
    import os

    from companion.errors import ConfigError
    from companion.run_folder import prepare_run_dir

    def full(_fd: int) -> None:
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "fsync", full)
    with pytest.raises(ConfigError, match="free some disk space"):
        prepare_run_dir(tmp_path / "run")
    assert [p.name for p in (tmp_path / "run").iterdir()] == ["checkpoints"]  # the probe is gone
