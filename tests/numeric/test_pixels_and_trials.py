"""The pin, end to end: the camera's pixels and a whole trial do not depend on the kernels
the shell asks for."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from colcommon import numeric_env as ne

ROOT = Path(__file__).resolve().parents[2]
CAN_PIN = ne.why_not_pinned({}, os.uname().machine, ne.cpu_flags()) is None
pytestmark = [pytest.mark.skipif(not CAN_PIN, reason="this CPU cannot run the x86-64-v3 profile"),
              pytest.mark.xdist_group("cpu-heavy"),  # lockstep: one CPU-heavy unit at a time
              pytest.mark.timeout(1500)]  # an upper bound: a trial rerun at load ~10


def _clean_env(**extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in ne.PINNED}
    return {**env, "PYTHONPATH": str(ROOT), **extra}


def _probe(env: dict[str, str]) -> dict[str, object]:
    out = subprocess.run([sys.executable, str(Path(__file__).with_name("pixel_probe.py"))], env=env,
                         capture_output=True, text=True, timeout=300, check=True, cwd=ROOT)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_pixels_and_detections_are_the_same_with_and_without_avx512() -> None:
    """OpenCV's and numpy's AVX-512 loops (what an x86-64-v4 CPU runs unpinned) draw and detect
    exactly what their AVX2 loops (the profile, and any AVX2 CPU) do."""
    native = _probe(_clean_env())
    pinned = _probe(_clean_env(**{k: ne.PINNED[k] for k in ("OPENCV_CPU_DISABLE", "NPY_DISABLE_CPU_FEATURES",
                                                            "OPENBLAS_CORETYPE")}))
    assert native["found"] and native == pinned


def _content(checkpoint: Path) -> dict[str, bytes]:
    """A checkpoint's arrays, byte for byte, and its metadata but for the time it was written."""
    with np.load(checkpoint) as npz:
        arrays = {k: npz[k].tobytes() for k in npz.files if k != "metadata"}
        metadata = json.loads(npz["metadata"].tobytes().decode())
    metadata.pop("created_utc")
    return {**arrays, "metadata": json.dumps(metadata, sort_keys=True).encode()}


def _quick_grid(out: Path, outside_kernel: str) -> tuple[str, dict[str, dict[str, bytes]], list[dict[str, object]]]:
    """``col experiment`` on the quick grid, the shell asking for ``outside_kernel``."""
    col = Path(sys.executable).with_name("col")
    subprocess.run([str(col), "experiment", "--config", str(ROOT / "configs/experiment_quick.toml"),
                    "--workers", "1", "--out", str(out)], env=_clean_env(OPENBLAS_CORETYPE=outside_kernel),
                   capture_output=True, text=True, timeout=900, check=True, cwd=ROOT)
    checkpoints = {str(p.relative_to(out)): _content(p) for p in sorted(out.glob("trials/*/train/checkpoints/*.npz"))}
    return (out / "results.jsonl").read_text(), checkpoints, ne.read_records(out)


def test_a_trial_is_identical_whatever_kernel_the_shell_asks_for(tmp_path: Path) -> None:
    """Two shells, two OpenBLAS kernels asked for (AVX-512 and SSE3): the same results lines and
    the same weights, byte for byte, because every process runs the project's profile (unpinned,
    the SkylakeX and Haswell kernels trained this grid's policies to different weights).
    Unpinned, the first committed grid's P3-col-04-s3 read 91 % with OpenBLAS's SkylakeX
    kernels and 95 % with its Haswell ones (docs/experiment.md, "Reproducible numbers")."""
    lines_a, checkpoints_a, records_a = _quick_grid(tmp_path / "a", "SkylakeX")
    lines_b, checkpoints_b, records_b = _quick_grid(tmp_path / "b", "Prescott")
    assert lines_a.count("\n") == 2 and lines_a == lines_b
    assert checkpoints_a and checkpoints_a == checkpoints_b
    for records in (records_a, records_b):
        (rec,) = records
        assert rec["profile"] == ne.PROFILE
        assert rec["variables"]["OPENBLAS_CORETYPE"] == "Haswell"
        assert [lib["architecture"] for lib in rec["blas"] if lib["internal_api"] == "openblas"] == ["Haswell"]
    # every training run's folder records the same environment (the SITL and worker inherit it)
    runs = sorted((tmp_path / "a").glob("trials/*/train"))
    assert runs and all(ne.read_records(r)[0]["variables"]["OPENBLAS_CORETYPE"] == "Haswell" for r in runs)
