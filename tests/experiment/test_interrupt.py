"""Ctrl-C on a running grid: no new run starts, the running ones finish and are kept, the
process exits. A SIGINT to the parent alone (as a job control or a supervisor sends it)
once left the grid running on, and a second grid on the same folder then ran the same
trials at once and destroyed each other's files."""

from __future__ import annotations

import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from companion.experiment.grid import ExperimentSetup, TrainingRun
from companion.experiment.results import TrialResult
from tests.conftest import wait_until

REPO = Path(__file__).resolve().parents[2]
RUN_S = 1.5


def slow_run(setup: ExperimentSetup, run: TrainingRun, out_dir: Path) -> list[TrialResult]:
    """Runs in a worker: marks its start, takes RUN_S, then gives ok results."""
    (out_dir / "started").mkdir(exist_ok=True)
    (out_dir / "started" / run.key).touch()
    time.sleep(RUN_S)
    return [TrialResult(trial=t, fingerprint=setup.fingerprint(), status="ok", eval_runs=1, eval_successes=1)
            for t in run.trials]


GRID = textwrap.dedent("""
    import sys
    from pathlib import Path
    from companion.config import CompanionConfig
    from companion.experiment.grid import ExperimentConfig, ExperimentSetup
    from companion.experiment.results import ResultsFile
    from companion.experiment.runner import run_grid
    from tests.experiment.test_interrupt import slow_run
    if sys.argv[2] == "while-writing":  # Ctrl-C lands while the parent records a result
        append = ResultsFile.append
        def interrupted(self, result):
            append(self, result)
            raise KeyboardInterrupt
        ResultsFile.append = interrupted
    exp = ExperimentConfig(participants=("P1", "P2", "P3", "P4"), conditions=("col",), interactions=(1, 2, 3))
    run_grid(ExperimentSetup(exp, CompanionConfig()), Path(sys.argv[1]), workers=2, progress=False,
             run_fn=slow_run)
""")


@pytest.mark.e2e
@pytest.mark.parametrize("when", ["sigint", "while-writing"])
def test_an_interrupted_grid_starts_no_new_run_keeps_what_finished_and_exits(tmp_path: Path, when: str) -> None:
    proc = subprocess.Popen([sys.executable, "-c", GRID, str(tmp_path), when], cwd=REPO,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    results = tmp_path / "results.jsonl"
    try:
        assert wait_until(lambda: results.exists() and results.read_text().count("\n") >= 1, 60.0)
        if when == "sigint":
            proc.send_signal(signal.SIGINT)  # to the parent alone
        proc.wait(timeout=4 * RUN_S + 10)
    finally:
        if proc.poll() is None:
            proc.kill()
    started = {p.name for p in (tmp_path / "started").iterdir()}
    # at most the runs under way and the one the pool had queued for the next free worker
    assert len(started) <= 7, f"the interrupted grid went on starting runs: {sorted(started)}"
    time.sleep(2 * RUN_S)  # a worker left behind would start another run by now
    assert {p.name for p in (tmp_path / "started").iterdir()} == started
    finished = results.read_text().splitlines()
    assert 1 <= len(finished) <= len(started)
