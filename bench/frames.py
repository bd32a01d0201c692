"""Benchmark: the wall-clock figures the tests no longer assert (they check the logic instead).

- ``publish_ms_p99`` / ``publish_ms_max``: ``FrameServer.publish(blocking=False)`` of 640x480 raw
  frames at 35 Hz to a reader that connected and never reads, until the server drops it
  (``dropped``); the real-time SITL's camera must never wait for a stalled viewer.
- ``guard_release_ms_p99``: a learner's ``ControlTickGuard.pause()`` inside a tick's window,
  released by the control loop's ``tick()`` 10 ms later: how long past the tick the learner
  stayed off the GIL.

The machine may be shared with other jobs, so times vary between runs; ``machine_ref_rt`` says
how fast it was. The last line of stdout is one JSON object.

    python bench/frames.py [--quick]
"""

from __future__ import annotations

import argparse
import json
import socket
import threading
import time

import numpy as np
from machine_ref import machine_ref_rt

from colcommon.frames import Frame
from companion.learning.runners import ControlTickGuard
from sitl.frames import FrameServer


def publish_to_a_stalled_reader(seconds: float) -> dict[str, float | bool]:
    frame = Frame(0, 0, np.random.default_rng(0).integers(0, 256, (480, 640, 3), dtype=np.uint8))
    with FrameServer(write_timeout_s=0.3) as server:
        stuck = socket.create_connection(("127.0.0.1", server.port))
        try:
            while server.client_count == 0:
                time.sleep(0.01)
            took_ms: list[float] = []
            end = time.monotonic() + seconds
            while server.client_count and time.monotonic() < end:
                start = time.perf_counter()
                server.publish(frame, blocking=False)
                took_ms.append((time.perf_counter() - start) * 1e3)
                time.sleep(1 / 35)
            dropped = server.client_count == 0
        finally:
            stuck.close()
    return {"publishes": len(took_ms), "publish_ms_p99": round(float(np.percentile(took_ms, 99)), 3),
            "publish_ms_max": round(max(took_ms), 3), "dropped": dropped}


def _one_release() -> float:
    """Milliseconds from the control loop's tick to the end of the learner's pause."""
    guard = ControlTickGuard(guard_s=0.05, period_s=0.1)
    guard.tick()
    time.sleep(0.06)  # inside the window [0.05, 0.15) of the tick expected at 0.1
    ticked: list[float] = []

    def tick() -> None:
        ticked.append(time.perf_counter())
        guard.tick()

    timer = threading.Timer(0.01, tick)
    timer.start()
    guard.pause()
    released = time.perf_counter()
    timer.join()
    return (released - ticked[0]) * 1e3 if ticked and released >= ticked[0] else float("nan")


def guard_release(rounds: int) -> dict[str, float]:
    late_ms = [_one_release() for _ in range(rounds)]
    return {"guard_rounds": rounds, "guard_release_ms_p99": round(float(np.nanpercentile(late_ms, 99)), 3)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="short run (a few seconds)")
    args = parser.parse_args()
    result = {"bench": "frames", "machine_ref_rt": round(machine_ref_rt(), 1)}
    result |= publish_to_a_stalled_reader(3.0 if args.quick else 10.0)
    result |= guard_release(10 if args.quick else 100)
    print(json.dumps(result))


if __name__ == "__main__":
    main()
