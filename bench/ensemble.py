"""Benchmark of the ensemble: inference of all K members per control step, and one update.

Per control step the companion flies the ensemble's mean action and computes the members'
disagreement (``EnsembleSnapshot.act_with_score`` on one observation); the goal is all K
members well within the 2 ms control-latency budget. Measured for K = 1 (the paper's single
network, ``PolicySnapshot.act``) and K = 2, 5, 10, as the median and 99th percentile over many
calls, with random weights (the time does not depend on their values). Also the learner's
update (all K members, each on its own minibatch of 64) and the threshold's recalibration
(disagreement on every state of a 5,000-sample dataset).

    python bench/ensemble.py [--quick]

Last line of stdout: one JSON object.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from machine_ref import machine_ref_rt  # noqa: E402

from companion.learning.ensemble import EnsembleSnapshot, EnsembleTrainer  # noqa: E402
from companion.learning.policy import Normalisation  # noqa: E402
from companion.learning.trainer import MlpTrainer, one_blas_thread  # noqa: E402

SIZES = (15, 130, 72, 40, 4)


def _stacks(k: int, rng: np.random.Generator) -> tuple[list[np.ndarray], list[np.ndarray]]:
    pairs = list(zip(SIZES[:-1], SIZES[1:], strict=True))
    return ([rng.normal(0, 0.1, (k, o, i)).astype(np.float32) for i, o in pairs],
            [rng.normal(0, 0.01, (k, o)).astype(np.float32) for _, o in pairs])


def _times_us(call: Callable[[], object], calls: int) -> np.ndarray:
    for _ in range(50):
        call()
    out = np.empty(calls)
    for i in range(calls):
        t0 = time.perf_counter()
        call()
        out[i] = time.perf_counter() - t0
    return out * 1e6


def inference(k: int, calls: int, rng: np.random.Generator) -> dict[str, float]:
    ws, bs = _stacks(k, rng)
    snap = EnsembleSnapshot.stack(ws, bs, Normalisation.identity())
    single = snap.member(0)
    obs = rng.normal(size=15).astype(np.float32)
    t = _times_us((lambda: single.act(obs)) if k == 1 else (lambda: snap.act_with_score(obs)), calls)
    return {"median_us": round(float(np.median(t)), 1), "p99_us": round(float(np.percentile(t, 99)), 1)}


def update_us(k: int, n: int, rng: np.random.Generator) -> float:
    ws, bs = _stacks(k, rng)
    mean, std = np.zeros(15, np.float32), np.ones(15, np.float32)
    if k == 1:
        single = MlpTrainer([w[0] for w in ws], [b[0] for b in bs], mean, std)
        obs1, act1 = rng.normal(size=(64, 15)).astype(np.float32), np.zeros((64, 4), np.float32)
        return float(np.median(_times_us(lambda: single.step(obs1, act1), n)))
    trainer = EnsembleTrainer(ws, bs, mean, std)
    obs, act = rng.normal(size=(k, 64, 15)).astype(np.float32), np.zeros((k, 64, 4), np.float32)
    return float(np.median(_times_us(lambda: trainer.step(obs, act), n)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="fewer calls (a smoke run)")
    args = parser.parse_args()
    machine_ref = machine_ref_rt(rounds=1, steps=2000) if args.quick else machine_ref_rt()
    one_blas_thread()
    rng = np.random.default_rng(0)
    calls, updates = (500, 50) if args.quick else (20000, 500)
    result: dict[str, object] = {"bench": "ensemble", "control_latency_goal_us": 2000}
    for k in (1, 2, 5, 10):
        inf = inference(k, calls, rng)
        result[f"act_k{k}_median_us"] = inf["median_us"]
        result[f"act_k{k}_p99_us"] = inf["p99_us"]
        result[f"update_k{k}_median_us"] = round(update_us(k, updates, rng), 1)
        print(f"K={k}: act+score median {inf['median_us']} us, p99 {inf['p99_us']} us; "
              f"one update of all members {result[f'update_k{k}_median_us']} us", file=sys.stderr)
    ws, bs = _stacks(5, rng)
    snap = EnsembleSnapshot.stack(ws, bs, Normalisation.identity())
    data = rng.normal(size=(5000, 15)).astype(np.float32)
    result["recalibrate_k5_5000_samples_ms"] = round(float(np.median(_times_us(lambda: snap.scores(data), 20))) / 1e3, 2)
    result["machine_ref_rt"] = round(machine_ref, 1)
    print(json.dumps(result))


if __name__ == "__main__":
    main()
