"""Benchmark: how fast the real autopilots' SITLs run against the wall clock on this machine.

PX4 SIH (``PX4_SIM_SPEED_FACTOR``) and ArduCopter SITL (``--speedup``) are asked to run N times
faster than real time; neither fails when the machine cannot keep up, each just runs slower. So
what a speed-up "holds" is measured: both started side by side, as the real-autopilot tests start
them, at the tests' priority (``--nice``, tests/conftest.py's REALTIME_NICE), optionally beside
``--busy-procs`` CPU-bound processes at nice 0, and for ``--seconds`` of wall time after a
warm-up the vehicle's boot clock (ATTITUDE's ``time_boot_ms``, asked at the companion's 50 Hz)
is compared with the wall clock: ``achieved`` over the whole window and ``worst_window`` over
5 s windows. This is the autopilots on the ground with nobody flying them; what they kept while
the companion flew is in the test module's own timing file (tests/autopilots).

    python bench/autopilot_speed.py --px4 4 --ardupilot 5 [--busy-procs 2] [--nice -10]

The machine may be shared with other jobs; ``machine_ref_rt`` and the load say how busy it was.
The last line of stdout is one JSON object.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import tempfile
import threading
import time
from pathlib import Path

from load import busy_processes
from machine_ref import machine_ref_rt
from pymavlink import mavutil

from companion.testing.autopilots import (
    RunningAutopilot,
    find_autopilots,
    start_ardupilot,
    start_px4,
)

WINDOW_S = 5.0


def clock_samples(ap: RunningAutopilot, warmup_s: float, seconds: float) -> list[tuple[float, float]]:
    """(wall s, vehicle s) of each ATTITUDE heard from ``warmup_s`` after the first for ``seconds``."""
    mav = mavutil.mavlink_connection(ap.connection, source_system=245)
    samples: list[tuple[float, float]] = []
    try:
        first: float | None = None
        next_ask = 0.0
        while True:
            now = time.monotonic()
            if now >= next_ask:  # ArduCopter streams only when asked; asked again in case it was lost
                mav.mav.command_long_send(1, 1, mavutil.mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                          mavutil.mavlink.MAVLINK_MSG_ID_ATTITUDE, 20_000, 0, 0, 0, 0, 0)
                next_ask = now + 2.0
            msg = mav.recv_match(type="ATTITUDE", blocking=True, timeout=0.5)
            if msg is None or msg.get_srcComponent() != 1:
                continue
            first = now if first is None else first
            if now - first >= warmup_s:
                samples.append((now, msg.time_boot_ms / 1000.0))
            if now - first >= warmup_s + seconds:
                return samples
    finally:
        mav.close()


def speed(samples: list[tuple[float, float]]) -> dict[str, float | int]:
    """The vehicle's seconds per wall second over the samples, and in the slowest 5 s window."""
    if len(samples) < 2:
        return {"samples": len(samples)}
    (w0, v0), (w1, v1) = samples[0], samples[-1]
    windows = []
    start = 0
    for i, (w, v) in enumerate(samples):
        if w - samples[start][0] >= WINDOW_S:
            windows.append((v - samples[start][1]) / (w - samples[start][0]))
            start = i
    return {"samples": len(samples), "wall_s": round(w1 - w0, 2), "vehicle_s": round(v1 - v0, 2),
            "achieved": round((v1 - v0) / (w1 - w0), 3), "worst_window": round(min(windows), 3) if windows else None}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--px4", type=float, default=4.0, help="PX4_SIM_SPEED_FACTOR (0: not started)")
    parser.add_argument("--ardupilot", type=float, default=5.0, help="ArduCopter --speedup (0: not started)")
    parser.add_argument("--seconds", type=float, default=30.0, help="wall seconds measured")
    parser.add_argument("--warmup-s", type=float, default=10.0, help="wall seconds after the first message, not measured")
    parser.add_argument("--busy-procs", type=int, default=0, help="CPU-bound processes at nice 0 beside them")
    parser.add_argument("--nice", type=int, default=-10, help="the autopilots' niceness (the tests': -10)")
    parser.add_argument("--quick", action="store_true", help="10 s measured after 5 s")
    args = parser.parse_args()
    if args.quick:
        args.seconds, args.warmup_s = 10.0, 5.0
    root, why = find_autopilots()
    if root is None:  # make bench runs every script: without the autopilots this one says why and passes
        print(json.dumps({"bench": "autopilot_speed", "skipped": why}))
        return
    machine_ref = machine_ref_rt()
    load_before = os.getloadavg()[0]
    results: dict[str, dict[str, float | int]] = {}
    with busy_processes(args.busy_procs, nice=0), tempfile.TemporaryDirectory(prefix="autopilot-speed-") as tmp:
        with contextlib.suppress(PermissionError):
            os.setpriority(os.PRIO_PROCESS, 0, args.nice)  # inherited by the autopilots
        started = {}
        if args.px4 > 0:
            started["px4"] = start_px4(root, Path(tmp) / "px4", speedup=args.px4)
        if args.ardupilot > 0:
            started["ardupilot"] = start_ardupilot(root, Path(tmp) / "ardupilot", speedup=args.ardupilot)
        try:
            def measure(kind: str) -> None:
                results[kind] = speed(clock_samples(started[kind], args.warmup_s, args.seconds))

            threads = [threading.Thread(target=measure, args=(k,)) for k in started]
            for t in threads:
                t.start()
            for t in threads:
                t.join()
        finally:
            for ap in started.values():
                ap.stop()
    asked = {"px4": args.px4, "ardupilot": args.ardupilot}
    print(json.dumps({"bench": "autopilot_speed", "machine_ref_rt": machine_ref, "load_1min_before": round(load_before, 2),
                      "load_1min_after": round(os.getloadavg()[0], 2), "busy_procs": args.busy_procs, "nice": args.nice,
                      "cpus": os.cpu_count(),
                      "autopilots": {k: {"speedup_asked": asked[k], **v} for k, v in results.items()}}))


if __name__ == "__main__":
    main()
