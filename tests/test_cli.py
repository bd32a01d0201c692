"""The ``col`` command line as a person meets it: stopping it, and what it leaves behind."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from companion import cli
from companion.app import RunOptions, RunResult
from companion.learning.dataset import load_csv
from companion.msg.episode import EpisodeRecord
from tests.conftest import wait_until


def col_command() -> list[str]:
    script = Path(sys.executable).with_name("col")
    return [str(script)] if script.exists() else [sys.executable, "-m", "companion.cli"]


def children_of(pid: int) -> list[int]:
    """Direct child processes of ``pid`` (Linux /proc)."""
    kids: list[int] = []
    for task in Path(f"/proc/{pid}/task").glob("*"):
        text = (task / "children").read_text() if (task / "children").exists() else ""
        kids += [int(k) for k in text.split()]
    return kids




@pytest.mark.e2e
@pytest.mark.skipif(not Path("/proc/self/task").exists(), reason="needs Linux /proc")
def test_sigterm_stops_col_fly_cleanly_with_its_sitl_and_keeps_the_data(tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    args = [*col_command(), "fly", "--pilot", "expert", "--episodes", "50", "--no-learn", "--run-dir", str(run_dir)]
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=dict(os.environ, OMP_NUM_THREADS="1"))
    sitl: list[int] = []
    try:
        # the record line comes right after its checkpoint: wait for it, not for the checkpoint
        records = run_dir / "episodes.jsonl"
        assert wait_until(lambda: records.exists() and records.read_text().strip() != "", 60.0), "no episode finished"
        sitl = children_of(proc.pid)
        assert sitl, "col fly runs the SITL as its child"
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=20)
        sitl_gone = wait_until(lambda: not any(Path(f"/proc/{pid}").exists() for pid in sitl), 10.0)
    finally:
        if proc.poll() is None:
            proc.kill()
        for pid in sitl:  # only if the test failed: do not leave an orphan SITL running
            if Path(f"/proc/{pid}").exists():
                os.kill(pid, signal.SIGKILL)
    assert proc.returncode == 130, err[-2000:]
    assert "interrupted" in err and str(run_dir) in err
    assert sitl_gone, "the SITL outlived col fly"
    episodes = len((run_dir / "episodes.jsonl").read_text().splitlines())
    assert episodes >= 1 and len(list((run_dir / "checkpoints").glob("episode_*.npz"))) >= episodes
    loaded = load_csv(run_dir / "human.csv")
    assert loaded.report.rows > 0 and loaded.report.skipped_rows == 0  # closed cleanly: nothing torn


def _record(episode: int) -> EpisodeRecord:
    return EpisodeRecord(episode=episode, phase="demonstration", seed=episode, steps=10, human_samples=10,
                         interventions=0, intervention_s=0.0, intervention_durations_s=(), outcome="touchdown",
                         success=True, touchdown_distance_m=0.1, touchdown_speed_m_s=0.2, policy_version=1,
                         dataset_size=10, sim_time_s=1.0, wall_time_s=0.1)


def test_col_demo_in_a_resumed_run_folder_continues_from_its_own_episodes(tmp_path: Path,
                                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    """A folder that already holds episodes 0-5: this demo's episodes are 6-8 and 9-11."""
    calls: list[RunOptions] = []
    evaluated: list[Path] = []

    def fake_run_episodes(cfg, opts, on_episode=None, **hooks):  # type: ignore[no-untyped-def]
        calls.append(opts)
        first = opts.first_episode or 6
        return RunResult(opts.run_dir, [_record(first + k) for k in range(opts.episodes)], dataset_size=100)

    def fake_evaluate(cfg, checkpoint, episodes, seed, run_dir, config, pictures=False):  # type: ignore[no-untyped-def]
        evaluated.append(checkpoint)
        return {"episodes": episodes, "successes": episodes, "success_rate": 1.0, "ci95": [0.7, 1.0]}

    monkeypatch.setattr("companion.app.run_episodes", fake_run_episodes)
    monkeypatch.setattr(cli, "evaluate", fake_evaluate)
    result = CliRunner().invoke(cli.app, ["demo", "--run-dir", str(tmp_path), "--eval-episodes", "1", "--no-pictures"])
    assert result.exit_code == 0, result.output
    demo_opts, int_opts = calls
    assert int_opts.checkpoint == tmp_path / "train" / "checkpoints" / "episode_008.npz"
    assert int_opts.first_episode == 9
    assert evaluated == [tmp_path / "train" / "checkpoints" / "episode_011.npz"]
