"""Whether the companion kept its control rate on the vehicle's clock.

The companion steps at ``control_rate_hz`` of the vehicle's time (its ``time_boot_ms``), however
fast the vehicle runs. On a busy machine, or with a SITL run faster than this machine can fly it
(PX4 SIH at 4x, ArduCopter at 5x), a step can take longer than its period: the vehicle flies on
the last setpoint meanwhile, and the person's or policy's corrections come late. The episode is
then not the one the policy was trained for, and its record should say so: in one CI run two of
the expert's episodes on PX4 SIH at 4x timed out with nothing in the record to tell the machine's
part (bench/results/ci-fresh-2026-12-07-37-failed.txt; the run's records were not kept).
"""

from __future__ import annotations

KEPT_FRACTION = 0.8  # below this share of the asked rate the episode's record says so
MIN_VEHICLE_S = 2.0  # a shorter episode's rate says little


def achieved_rate_hz(steps: int, vehicle_s: float) -> float | None:
    """Control steps per second of the vehicle's time (None: too short an episode to tell)."""
    if vehicle_s < MIN_VEHICLE_S or steps <= 0:
        return None
    return steps / vehicle_s


def pace_note(steps: int, vehicle_s: float, rate_hz: float) -> str | None:
    """The record's note when the episode ran below :data:`KEPT_FRACTION` of ``rate_hz`` of the
    vehicle's time; None when it kept its rate (or was too short to tell)."""
    achieved = achieved_rate_hz(steps, vehicle_s)
    if achieved is None or achieved >= KEPT_FRACTION * rate_hz:
        return None
    return (f"control kept {achieved:.1f} of {rate_hz:g} steps a second of the vehicle's time: the companion fell "
            "behind the vehicle (a busy machine, or a SITL faster than this machine flies); its steps were longer "
            "than the policy learned with")
