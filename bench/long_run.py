"""Long run: many lockstep episodes in one process with the learner on, watching the companion's
resident memory, open file descriptors, threads and speed episode by episode.

Each episode appends one JSON line to ``--progress`` (so a run cut short still tells how far it
got); the last line printed is one JSON object: growth after the first ``--warmup`` episodes.
The dataset grows with every demonstration (kept in memory for training, as designed), so the
memory growth it explains is reported beside the raw figure.

    nice -n 10 python bench/long_run.py --episodes 1000 --progress long_run.jsonl
    python bench/long_run.py --summarise long_run.jsonl --warmup 50   # figures of a run cut short
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from machine_ref import machine_ref_rt  # noqa: E402

from companion.app import RunOptions, run_episodes  # noqa: E402
from companion.config import load_companion_config  # noqa: E402
from companion.testing.fuzz_targets import rss_kib  # noqa: E402

BYTES_PER_SAMPLE = 4 * (15 + 4) + 1  # what the dataset keeps in memory: float32 observation and action, a bool


def _sample(episode: int, steps: int, t0: float, dataset: int) -> dict[str, float | int]:
    return {
        "episode": episode, "steps": steps, "wall_s": round(time.monotonic() - t0, 3),
        "cpu_s": round(time.process_time(), 3),  # this process, learner thread included: load-proof
        "rss_kib": rss_kib(os.getpid()), "fds": len(os.listdir("/proc/self/fd")),
        "threads": threading.active_count(), "dataset": dataset,
    }


def summarise(rows: list[dict], warmup: int) -> dict[str, object]:
    """Growth from episode ``warmup`` to the last one; speed of the first and last 100 after it."""
    if len(rows) <= warmup:
        return {"episodes_done": len(rows)}
    base, last = rows[warmup - 1], rows[-1]
    dataset_kib = (last["dataset"] - base["dataset"]) * BYTES_PER_SAMPLE / 1024

    def speed(part: list[dict]) -> float:  # steps per wall second
        steps = sum(r["steps"] for r in part)
        wall = part[-1]["wall_s"] - part[0]["wall_s"] if len(part) > 1 else 0.0
        return round(steps / wall, 1) if wall > 0 else 0.0

    def cpu_ms(part: list[dict]) -> float | None:  # CPU per step: what other processes do not change
        if len(part) < 2 or "cpu_s" not in part[0]:
            return None
        steps = sum(r["steps"] for r in part[1:])
        return round(1000 * (part[-1]["cpu_s"] - part[0]["cpu_s"]) / steps, 3) if steps else None

    window = max(2, min(100, (len(rows) - warmup) // 2))
    return {
        "episodes_done": len(rows),
        "rss_kib_at_warmup": base["rss_kib"], "rss_kib_end": last["rss_kib"],
        "rss_growth_pct": round(100 * (last["rss_kib"] - base["rss_kib"]) / base["rss_kib"], 2),
        "rss_growth_pct_without_dataset": round(100 * (last["rss_kib"] - base["rss_kib"] - dataset_kib) / base["rss_kib"], 2),
        "dataset_samples": last["dataset"],
        "fds_at_warmup": base["fds"], "fds_end": last["fds"],
        "threads_at_warmup": base["threads"], "threads_end": last["threads"],
        "steps_per_s_after_warmup": speed(rows[warmup:warmup + window]),
        "steps_per_s_last": speed(rows[-window:]),
        "cpu_ms_per_step_after_warmup": cpu_ms(rows[warmup:warmup + window]),
        "cpu_ms_per_step_last": cpu_ms(rows[-window:]),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=1000)
    ap.add_argument("--warmup", type=int, default=100)
    ap.add_argument("--progress", type=Path, default=Path("long_run.jsonl"))
    ap.add_argument("--summarise", type=Path, help="instead of running: summarise this progress file (a run cut short)")
    args = ap.parse_args()
    if args.summarise is not None:
        done = [json.loads(x) for x in args.summarise.read_text().splitlines() if x.strip()]
        print(json.dumps({**summarise(done, args.warmup), "warmup": args.warmup, "cut_short": True}))
        return
    machine_ref = machine_ref_rt()
    cfg = load_companion_config(None)
    rows: list[dict] = []
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="col-long-") as work, args.progress.open("w") as progress:
        def on_episode(record) -> None:  # type: ignore[no-untyped-def]
            rows.append(_sample(record.episode, record.steps, t0, record.dataset_size))
            progress.write(json.dumps(rows[-1]) + "\n")
            progress.flush()

        opts = RunOptions(pilot="expert", condition="demo", episodes=args.episodes, run_dir=Path(work) / "run",
                          learn=True, lockstep=True)
        try:
            run_episodes(cfg, opts, on_episode)
        except KeyboardInterrupt:
            pass
    print(json.dumps({**summarise(rows, args.warmup), "machine_ref_rt": round(machine_ref, 1)}))


if __name__ == "__main__":
    main()
