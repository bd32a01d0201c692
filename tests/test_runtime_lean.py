"""The lean flight runtime: ``col fly --checkpoint ... --condition eval`` and the SITL it starts run
with torch (and every other package of the optional extras) made unimportable
(:mod:`companion.testing.lean`), and fly exactly the setpoints that the full install flies from
the same checkpoint and seed.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from pymavlink import mavutil

from companion.config import LearnerConfig
from companion.learning.checkpoint import save_checkpoint
from companion.learning.snapshot import Normalisation, PolicySnapshot
from companion.testing.lean import NOT_IN_THE_LEAN_INSTALL
from companion.testing.lean import lean_env as _lean_env

pytestmark = pytest.mark.e2e

REPO = Path(__file__).resolve().parents[1]


def lean_env(tmp_path: Path) -> dict[str, str]:
    """An environment in which the training stack cannot be imported."""
    return {**_lean_env(tmp_path / "lean-site", prepend=[str(REPO)]), "OMP_NUM_THREADS": "1"}


def full_env() -> dict[str, str]:
    path = os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])
    return dict(os.environ, PYTHONPATH=path, OMP_NUM_THREADS="1")


def a_checkpoint(path: Path) -> Path:
    """A seeded policy with non-trivial weights and normalisation (no torch needed to write it)."""
    rng = np.random.default_rng(7)
    sizes = (15, 130, 72, 40, 4)
    weights = [rng.normal(0, 0.15, (o, i)) for i, o in zip(sizes[:-1], sizes[1:])]
    biases = [rng.normal(0, 0.05, o) for o in sizes[1:]]
    norm = Normalisation(rng.normal(0, 0.5, 15), rng.uniform(0.5, 2.0, 15))
    snapshot = PolicySnapshot(tuple(weights), tuple(biases), norm, version=3, dataset_size_trained=10)
    return save_checkpoint(path, snapshot, LearnerConfig(), dataset_size=10, episode=0, condition="col")


def fly_eval(checkpoint: Path, run_dir: Path, env: dict[str, str]) -> dict[str, object]:
    args = [sys.executable, "-m", "companion.cli", "fly", "--checkpoint", str(checkpoint), "--condition", "eval",
            "--pilot", "none", "--episodes", "1", "--seed", "11", "--run-dir", str(run_dir)]
    done = subprocess.run(args, capture_output=True, text=True, timeout=240, env=env, cwd=run_dir.parent)
    assert done.returncode == 0, f"col fly failed ({done.returncode}):\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}"
    return dict(json.loads(done.stdout.strip().splitlines()[-1]))


def sent_setpoints(tlog: Path) -> list[tuple[float, float, float, float]]:
    """The velocity setpoints ``col`` sent, in order, as the telemetry log holds them."""
    log = mavutil.mavlink_connection(str(tlog), dialect="common")
    out = []
    try:
        while (msg := log.recv_match(type="SET_POSITION_TARGET_LOCAL_NED")) is not None:
            out.append((msg.vx, msg.vy, msg.vz, msg.yaw_rate))
    finally:
        log.close()
    return out


def test_the_blocker_makes_torch_unimportable(tmp_path: Path) -> None:
    probe = "import importlib.util, sys\ntry:\n    import torch\nexcept ImportError:\n    sys.exit(3)\n"
    assert subprocess.run([sys.executable, "-c", probe], env=lean_env(tmp_path)).returncode == 3


def test_lean_modules_import_without_the_training_stack(tmp_path: Path) -> None:
    probe = ("import sys, companion.cli, companion.app, companion.learning.checkpoint, sitl.cli, sitl.server\n"
             f"assert not set(sys.modules) & {set(NOT_IN_THE_LEAN_INSTALL)!r}, sorted(sys.modules)\n")
    done = subprocess.run([sys.executable, "-c", probe], env=lean_env(tmp_path), capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-3000:]


def test_sitl_help_runs_without_the_training_stack(tmp_path: Path) -> None:
    done = subprocess.run([sys.executable, "-m", "sitl", "--help"], env=lean_env(tmp_path),
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "--clock" in done.stdout


def test_a_fresh_policy_without_torch_learns_from_a_numpy_draw(tmp_path: Path) -> None:
    """CoL from scratch on the lean runtime: the initial weights come from NumPy, training is
    NumPy's anyway; the expert demonstrates one episode and the policy learns from it."""
    args = [sys.executable, "-m", "companion.cli", "fly", "--condition", "col", "--episodes", "2",
            "--seed", "0", "--run-dir", str(tmp_path / "run")]
    done = subprocess.run(args, env=lean_env(tmp_path), capture_output=True, text=True, timeout=240)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "drawn by NumPy" in done.stderr
    summary = json.loads(done.stdout.strip().splitlines()[-1])
    assert summary["episodes"] == 2 and summary["human_samples"] > 0
    assert summary["policy_version"] > 0 and summary["learner_error"] is None


def test_lean_install_flies_the_same_setpoints_as_the_full_install(tmp_path: Path) -> None:
    checkpoint = a_checkpoint(tmp_path / "policy.npz")
    lean = fly_eval(checkpoint, tmp_path / "lean", lean_env(tmp_path))
    full = fly_eval(checkpoint, tmp_path / "full", full_env())
    lean_sp = sent_setpoints(tmp_path / "lean" / "session.tlog")
    full_sp = sent_setpoints(tmp_path / "full" / "session.tlog")
    assert len(lean_sp) > 20  # the policy flew a real episode
    assert len({sp for sp in lean_sp}) > 5  # and its commands changed as the vehicle moved
    assert lean_sp == full_sp
    assert lean["episodes"] == full["episodes"] == 1
    assert lean["success_rate"] == full["success_rate"]


def test_export_without_the_onnx_extra_says_what_to_install(tmp_path: Path) -> None:
    checkpoint = a_checkpoint(tmp_path / "policy.npz")
    base = [sys.executable, "-m", "companion.cli", "export", str(checkpoint)]
    onnx = subprocess.run([*base, "--format", "onnx"], env=lean_env(tmp_path), capture_output=True, text=True,
                          timeout=120)
    assert onnx.returncode == 2 and "pip install '.[onnx]'" in onnx.stderr
    npz = subprocess.run([*base, "--format", "npz"], env=lean_env(tmp_path), capture_output=True, text=True,
                         timeout=120)
    assert npz.returncode == 0, npz.stderr[-2000:]
    assert (tmp_path / "policy.export.npz").is_file()
