"""Benchmark: the lean flight runtime (no torch) and the policy's exports.

- ``policy_act_us_p99`` (goal <= 20): one ``PolicySnapshot.act`` on one observation, the 15-130-
  72-40-4 policy loaded from a checkpoint, in a process where the extras' packages (torch...)
  cannot be imported (:mod:`companion.testing.lean`); p50 and p99 over ``--acts`` calls.
- ``fly_start_s`` (goal <= 1.5): a real-time SITL already running, ``col fly --connect ...
  --simulator ... --checkpoint ... --condition eval --pilot none`` started in that lean
  environment; from the process's start to the first SET_POSITION_TARGET_LOCAL_NED it sends
  (the send time in its telemetry log, on the wall clock). Median of ``--starts`` runs. Beside
  it ``fly_import_cpu_s``: the CPU time a lean process spends importing what ``col fly`` needs
  (best of 3), the bulk of the start and a figure that load hardly moves.
- ``fly_rss_mb`` (goal <= 150): the peak resident memory of that ``col fly`` process (``wait4``'s
  ``ru_maxrss``), stopped with SIGTERM ``--fly-s`` seconds after its start once it has sent a
  setpoint; the largest of the runs.
- ``onnx_max_abs_err`` (goal <= 1e-5): ``col export --format onnx`` of the checkpoint, run by
  onnxruntime on 1,000 random observations against the torch policy (needs the full install).
- ``runtime_image_mb`` (goal <= 400): the size podman reports for the image ``make
  image-check`` built, where it was built on this machine (else null).

    python bench/runtime.py [--quick] [--acts N] [--starts N] [--fly-s S]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from machine_ref import machine_ref_rt
from pymavlink import mavutil

from companion.config import LearnerConfig
from companion.learning.checkpoint import save_checkpoint
from companion.learning.snapshot import Normalisation, PolicySnapshot, random_snapshot
from companion.simulator import start_sitl
from companion.testing.lean import lean_env

REPO = Path(__file__).resolve().parents[1]
IMAGE = os.environ.get("COL_IMAGE", "localhost/cycle-of-learning:runtime")

ACT_PROBE = """
import json, sys, time
import numpy as np
from companion.learning.checkpoint import load_checkpoint
snap, _ = load_checkpoint(sys.argv[1])
obs = np.random.default_rng(0).normal(0, 1, (int(sys.argv[2]), 15)).astype(np.float32)
for o in obs[:200]:
    snap.act(o)
times = []
for o in obs:
    t0 = time.perf_counter_ns()
    snap.act(o)
    times.append(time.perf_counter_ns() - t0)
assert "torch" not in sys.modules
print(json.dumps(times))
"""


def a_checkpoint(folder: Path) -> Path:
    """The paper's policy shape with a fixed draw and a non-trivial normalisation."""
    rng = np.random.default_rng(1)
    base = random_snapshot(15, (130, 72, 40), init_std=0.1, seed=1)
    snap = PolicySnapshot(base.weights, base.biases, Normalisation(rng.normal(0, 1, 15), rng.uniform(0.5, 2, 15)))
    return save_checkpoint(folder / "policy.npz", snap, LearnerConfig(), dataset_size=0, episode=0, condition="col")


def policy_act(checkpoint: Path, env: dict[str, str], n: int) -> dict[str, float]:
    done = subprocess.run([sys.executable, "-c", ACT_PROBE, str(checkpoint), str(n)], env=env,
                          capture_output=True, text=True, check=True)
    us = np.array(json.loads(done.stdout.strip().splitlines()[-1])) / 1000.0
    return {"policy_act_us_p50": round(float(np.percentile(us, 50)), 2),
            "policy_act_us_p99": round(float(np.percentile(us, 99)), 2)}


IMPORTS = ("import companion.cli, companion.app, pymavlink.mavutil, pymavlink.dialects.v20.ardupilotmega, "
           "companion.learning.runners")


def import_cpu_s(env: dict[str, str], runs: int = 3) -> float:
    """CPU time (user + system) of a lean process importing what ``col fly`` imports before its
    first setpoint: most of ``fly_start_s``, and unlike it hardly changed by other load."""
    best = float("inf")
    for _ in range(runs):
        proc = subprocess.Popen([sys.executable, "-c", IMPORTS], env=env)
        _, status, usage = os.wait4(proc.pid, 0)
        if os.waitstatus_to_exitcode(status) != 0:
            raise RuntimeError("the lean imports failed")
        best = min(best, usage.ru_utime + usage.ru_stime)
    return best


def first_sent_setpoint_s(tlog: Path) -> float | None:
    """Wall time (s) of the first SET_POSITION_TARGET_LOCAL_NED the companion sent."""
    if not tlog.exists():
        return None
    log = mavutil.mavlink_connection(str(tlog), dialect="common")
    try:
        msg = log.recv_match(type="SET_POSITION_TARGET_LOCAL_NED")
        return None if msg is None else float(msg._timestamp)  # the record's time (tlog header)
    finally:
        log.close()


def fly_once(checkpoint: Path, env: dict[str, str], work: Path, fly_s: float) -> tuple[float | None, float]:
    """One ``col fly`` against a fresh real-time SITL: (start to first setpoint s, peak RSS MB)."""
    port = _free_udp_port()
    sitl = start_sitl(port, clock="realtime", timeout_s=120.0)
    run_dir = work / f"run-{port}"
    try:
        args = [sys.executable, "-m", "companion.cli", "fly", "--connect", f"udpin:127.0.0.1:{port}",
                "--simulator", f"127.0.0.1:{sitl.control_port}", "--checkpoint", str(checkpoint),
                "--condition", "eval", "--pilot", "none", "--episodes", "1", "--run-dir", str(run_dir)]
        t0 = time.time()
        proc = subprocess.Popen(args, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        deadline = time.monotonic() + fly_s + 90  # a loaded machine may take long to start
        while proc.poll() is None and time.monotonic() < deadline and not _flown(run_dir, fly_s, t0):
            time.sleep(1.0)
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)  # stops cleanly: the telemetry log is closed
        _, status, usage = os.wait4(proc.pid, 0)
        proc.returncode = os.waitstatus_to_exitcode(status)
        first = first_sent_setpoint_s(run_dir / "session.tlog")
        return (None if first is None else first - t0), usage.ru_maxrss / 1024.0
    finally:
        sitl.stop()


def _flown(run_dir: Path, fly_s: float, t0: float) -> bool:
    """Flown long enough: ``fly_s`` since the start, and a setpoint already in the log (flushed
    every 50 records, so it shows up a little after it was sent)."""
    return time.time() - t0 > fly_s and first_sent_setpoint_s(run_dir / "session.tlog") is not None


def _free_udp_port() -> int:
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def onnx_error(checkpoint: Path, work: Path) -> float | None:
    try:
        import onnxruntime as ort
        import torch

        from companion.learning.checkpoint import load_checkpoint
        from companion.learning.export import export_checkpoint
        from companion.learning.policy import PolicyNet
    except ImportError:
        return None
    path = export_checkpoint(checkpoint, "onnx", work / "policy.onnx")
    net = PolicyNet.from_snapshot(load_checkpoint(checkpoint)[0])
    obs = np.random.default_rng(5).normal(0, 2, (1000, 15)).astype(np.float32)
    with torch.no_grad():
        expected = net(torch.from_numpy(obs)).numpy()
    got = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"]).run(["actions"], {"obs": obs})[0]
    return float(np.max(np.abs(got - expected)))


def image_mb() -> float | None:
    if shutil.which("podman") is None:
        return None
    env = dict(os.environ, CONTAINERS_CONF=str(REPO / "docker" / "containers.conf"))
    done = subprocess.run(["podman", "image", "inspect", IMAGE, "--format", "{{.Size}}"], env=env,
                          capture_output=True, text=True)
    return round(int(done.stdout.strip()) / 1e6, 1) if done.returncode == 0 else None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="fewer calls and one start")
    parser.add_argument("--acts", type=int, default=20_000, help="policy calls timed")
    parser.add_argument("--starts", type=int, default=3, help="col fly starts measured")
    parser.add_argument("--fly-s", type=float, default=8.0, help="seconds each col fly runs before it is stopped")
    args = parser.parse_args()
    acts, starts = (2_000, 1) if args.quick else (args.acts, args.starts)
    ref = machine_ref_rt(rounds=1 if args.quick else 3)
    with tempfile.TemporaryDirectory(prefix="col-bench-runtime-") as tmp:
        work = Path(tmp)
        env = {**lean_env(work / "lean-site", prepend=[str(REPO)]), "OMP_NUM_THREADS": "1"}
        checkpoint = a_checkpoint(work)
        out: dict[str, Any] = policy_act(checkpoint, env, acts)
        flights = [fly_once(checkpoint, env, work, args.fly_s) for _ in range(starts)]
        started = [s for s, _ in flights if s is not None]
        out["fly_start_s"] = round(statistics.median(started), 3) if started else None
        out["fly_start_s_all"] = [None if s is None else round(s, 3) for s, _ in flights]
        out["fly_rss_mb"] = round(max(r for _, r in flights), 1)
        out["fly_import_cpu_s"] = round(import_cpu_s(env), 3)
        err = onnx_error(checkpoint, work)
        out["onnx_max_abs_err"] = None if err is None else float(f"{err:.3g}")
    out["runtime_image_mb"] = image_mb()
    out["goals"] = {"policy_act_us_p99": 20, "fly_start_s": 1.5, "fly_rss_mb": 150, "onnx_max_abs_err": 1e-5,
                    "runtime_image_mb": 400}
    out["load_avg_1m"] = round(os.getloadavg()[0], 2)
    out["machine_ref_rt"] = round(ref, 1)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
