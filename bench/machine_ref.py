"""A machine reference: how fast this machine runs JSBSim's shipped F450, as a real-time factor.

Every bench prints ``machine_ref_rt`` beside its own figures, measured in the same run (at its
start), so that figures taken on different machines, or on one machine under different load,
can be compared: divide a throughput by ``machine_ref_rt``, or compare ratios (see README.md).

The reference is the unmodified F450 that the ``jsbsim`` package ships (not the derived model of
``sitl/dynamics.py``) and nothing of this project, so it only moves with the machine, its load
and the jsbsim version. Per round, on a fresh ``FGFDMExec``:

- ``FGFDMExec(jsbsim.get_default_root_dir())``, ``set_debug_level(0)``, ``load_model("F450")``,
  ``set_dt(1/120)``, ``ic/h-sl-ft`` = 300 (the default terrain is at 0 ft, so 300 ft above it);
- all four motors at the constant hover command ``HOVER_THROTTLE`` (``fcs/throttle-cmd-norm``,
  which the model's mixer sends to every ESC): with the throttle at 0 the shipped model falls,
  hits the ground at about 5 s and its state turns NaN about 28 s in, so the steps would not be
  the same work as flight;
- ``run_ic()``, 48 untimed ``run()`` calls to spin the propellers up to hover speed, ``run_ic()``
  again (propeller speed survives it): the vehicle is back at 300 ft, at rest, hovering;
- timed: 20,000 ``run()`` calls (166.7 s of flight; the vehicle stays within 0.1 ft of 300 ft,
  checked after every round).

Result: the best round's steps per second divided by 120, i.e. how many times faster than real
time. JSBSim's console output (banner, "incompatible CFG file" notice, "failed to tie property"
lines) is swallowed by a silent logger for the duration; the caller's logger is restored.
Note that ``set_debug_level`` sets JSBSim's process-wide debug level (the SITL sets 0 as well).

    python bench/machine_ref.py [--quick] [--rounds N] [--steps N]

From another bench script (``bench/`` is ``sys.path[0]`` when a script in it is run)::

    from machine_ref import machine_ref_rt
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

import jsbsim

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from sitl.dynamics import SilentLogger  # noqa: E402  (the SITL's own: JSBSim's chatter off)

DT_S = 1.0 / 120.0
RATE_HZ = 120.0
ALTITUDE_FT = 300.0
# ESC command at which the shipped F450 neither climbs nor sinks at 300 ft (found by bisection
# on jsbsim 1.3.3; 0.416 climbs about 5 ft/s). HOLD_TOLERANCE_FT catches a model that changed.
HOVER_THROTTLE = 0.40826
SPIN_UP_STEPS = 48
HOLD_TOLERANCE_FT = 10.0


def _hovering_f450() -> jsbsim.FGFDMExec:
    """A fresh executive with the shipped F450 hovering at 300 ft, propellers at speed."""
    fdm = jsbsim.FGFDMExec(jsbsim.get_default_root_dir())
    fdm.set_debug_level(0)
    if not fdm.load_model("F450"):
        raise RuntimeError("JSBSim could not load its shipped F450 model")
    fdm.set_dt(DT_S)
    fdm["ic/h-sl-ft"] = ALTITUDE_FT
    fdm["fcs/throttle-cmd-norm"] = HOVER_THROTTLE
    fdm.run_ic()
    for _ in range(SPIN_UP_STEPS):
        fdm.run()
    fdm.run_ic()
    return fdm


def _check_holds(fdm: jsbsim.FGFDMExec) -> None:
    agl_ft = fdm["position/h-agl-ft"]
    if not (math.isfinite(agl_ft) and abs(agl_ft - ALTITUDE_FT) <= HOLD_TOLERANCE_FT):
        raise RuntimeError(
            f"machine reference: the F450 did not hold {ALTITUDE_FT:g} ft (at {agl_ft} ft after "
            f"the run); jsbsim {jsbsim.__version__} may ship a changed model"
        )


def _timed_rounds(rounds: int, steps: int) -> list[tuple[float, float]]:
    """(wall seconds, this thread's CPU seconds) of ``steps`` ``run()`` calls, per round."""
    if rounds < 1 or steps < 1:
        raise ValueError(f"rounds and steps must be >= 1; got rounds={rounds}, steps={steps}")
    previous = jsbsim.get_logger()
    jsbsim.set_logger(SilentLogger())
    try:
        times = []
        for _ in range(rounds):
            fdm = _hovering_f450()
            run = fdm.run
            cpu0, start = time.thread_time(), time.perf_counter()
            for _ in range(steps):
                run()
            wall_s, cpu_s = time.perf_counter() - start, time.thread_time() - cpu0
            _check_holds(fdm)
            times.append((wall_s, cpu_s))
            del fdm
        return times
    finally:
        jsbsim.set_logger(previous)


def machine_ref_rts(rounds: int = 3, steps: int = 20_000) -> list[float]:
    """The real-time factor of each round (see :func:`machine_ref_rt`)."""
    return [steps / wall_s / RATE_HZ for wall_s, _ in _timed_rounds(rounds, steps)]


def machine_ref_rt(rounds: int = 3, steps: int = 20_000) -> float:
    """How many times faster than real time this machine runs JSBSim's shipped F450 at 120 Hz.

    Best of ``rounds`` rounds, each a fresh ``FGFDMExec`` hovering at 300 ft and timed over
    ``steps`` ``run()`` calls: steps per second divided by 120. Wall-clock time, like the
    benches' own figures, so it also drops when another process shares this core. Takes under
    a second at the defaults (about 7 us per step on the development machine, plus set-up).
    Raises ``RuntimeError`` if the model does not load or does not hold its altitude.
    Compare figures only at the default ``rounds`` and ``steps``.
    """
    return max(machine_ref_rts(rounds, steps))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true",
                        help="accepted for `make bench` symmetry; the reference is already quick "
                             "(under a second) and is always the full definition")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--steps", type=int, default=20_000)
    args = parser.parse_args()
    times = _timed_rounds(args.rounds, args.steps)
    factors = [args.steps / wall_s / RATE_HZ for wall_s, _ in times]
    # Not part of the figure: the share of a core each round got (CPU time / wall time). Below
    # about 0.9 another process shared the core and machine_ref_rt is lowered by as much.
    shares = [cpu_s / wall_s for wall_s, cpu_s in times]
    print(f"JSBSim {jsbsim.__version__} F450 at 120 Hz, {args.steps} steps x {args.rounds} rounds: "
          f"{', '.join(f'{f:.1f}' for f in factors)}x real time; share of a core "
          f"{', '.join(f'{c:.2f}' for c in shares)}; "
          f"load average {os.getloadavg()[0]:.2f}, {os.cpu_count()} CPUs")
    print(json.dumps({"machine_ref_rt": round(max(factors), 1)}))


if __name__ == "__main__":
    main()
