"""A loaded machine on purpose, for the benches that measure under load (``busy_processes``).

Run as a script it measures what that load does: ``machine_ref_rt`` idle, then beside 1 and 2
busy processes (at niceness 0, as ``autopilot_speed.py`` loads the machine), so a figure taken
under ``--busy-procs N`` can be read against the reference it had::

    python bench/load.py [--quick]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import subprocess
import sys
from collections.abc import Iterator


@contextlib.contextmanager
def busy_processes(n: int, nice: int | None = None) -> Iterator[None]:
    """``n`` CPU-bound processes for the block (at ``nice``, if given: CI's other tests, roughly,
    whatever the bench's own niceness)."""
    def set_nice() -> None:
        if nice is not None:
            os.setpriority(os.PRIO_PROCESS, 0, nice)

    procs = [subprocess.Popen([sys.executable, "-c", "while True: pass"], preexec_fn=set_nice) for _ in range(n)]
    try:
        yield
    finally:
        for p in procs:
            p.kill()
            p.wait()


def main() -> None:
    from machine_ref import machine_ref_rt

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="one round of 5,000 steps per load (else 3 of 20,000)")
    args = parser.parse_args()
    rounds, steps = (1, 5_000) if args.quick else (3, 20_000)
    idle = machine_ref_rt(rounds, steps)
    loaded = {}
    for n in (1, 2):
        with busy_processes(n, nice=0):
            loaded[n] = machine_ref_rt(rounds, steps)
    print(json.dumps({"bench": "load", "machine_ref_rt": round(idle, 1),
                      "machine_ref_rt_busy_1": round(loaded[1], 1), "machine_ref_rt_busy_2": round(loaded[2], 1),
                      "slowdown_busy_2": round(idle / loaded[2], 2), "cpus": os.cpu_count(),
                      "rounds": rounds, "steps": steps}))


if __name__ == "__main__":
    main()
