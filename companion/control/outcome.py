"""How an episode ends and how it is scored: the one rule every driver of an episode uses.

The session (:class:`~companion.control.session.EpisodeRunner`), the Gymnasium env, the batched
env and the batched evaluation all judge each new frame with :func:`judge_frame` and score the
ended episode with :func:`score`; nothing else decides an outcome or a success. Pure: the drivers
bring the facts (steps taken, the landed state, the fence's verdict, the simulator's touchdown).

On a vehicle the companion flies, :func:`judge_vehicle` adds what the touchdown assist knows: its
evidence of a touchdown where the vehicle cannot say, and that a vehicle standing is not below
the fence. :func:`score_vehicle` scores an episode on what the vehicle offers: the simulator's
truth where there is one, else (:func:`score_estimate`) its position relative to home and its
autopilot's truth beside it, with the notes for the record.

The order of :func:`judge_frame` is the session's: the time limit first (a frame after the last
step is not looked at), then a touchdown (never on the episode's first frame: the vehicle may
still stand from the reset), then the geofence, which is not judged on telemetry that is not
finite (the driver holds that step instead).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from companion.control.safety import FenceStatus, Geofence
from companion.control.touchdown import Evidence, TouchdownAssist, touchdown_evidence
from companion.control.truth_contact import TruthGround
from companion.errors import ColError
from companion.link.home import HomeFrame
from companion.link.truth import true_distance_m as truth_distance_m
from companion.msg.snapshot import VehicleSnapshot

TOUCHDOWN = "touchdown"
FENCE = "fence"
TIMEOUT = "timeout"
DISTANCE_DECIMALS = 4


def judge_frame(steps_taken: int, max_steps: int, touched_down: bool, fence: FenceStatus | None) -> str | None:
    """Whether the episode ends at this frame, before its step is flown: "timeout", "touchdown",
    "fence", or None (fly the step). ``fence`` None: the telemetry is unusable, not judged."""
    if steps_taken >= max_steps:
        return TIMEOUT
    if steps_taken > 0 and touched_down:
        return TOUCHDOWN
    if fence is not None and not fence.inside:
        return FENCE
    return None


def telemetry_usable(snap: VehicleSnapshot) -> bool:
    """Whether the telemetry a step observes (position, attitude, velocity, rates) is finite:
    else the step holds, and the fence does not judge it."""
    values = (*snap.position_ned_m, *snap.attitude_rad, *snap.velocity_ned_m_s, *snap.rates_frd_rad_s)
    return math.isfinite(sum(values))  # a NaN or an infinity makes the sum so (finite values this size never overflow)


def judge_snapshot(steps_taken: int, max_steps: int, snap: VehicleSnapshot, fence: Geofence | None,
                   home: HomeFrame, touched_down: bool | None = None, standing: bool = False) -> str | None:
    """:func:`judge_frame` on a vehicle's telemetry: its landed state (or the companion's own
    evidence, ``touched_down``), and ``fence`` on the position relative to ``home`` (None: the
    companion keeps no fence, e.g. while the autopilot lands by itself). ``standing``: the
    touchdown assist's evidence that the vehicle stands (the fence's floor is not checked)."""
    down = snap.landed_state == "ON_GROUND" if touched_down is None else touched_down
    status = None
    if fence is not None and telemetry_usable(snap):
        status = fence.check(home.relative(snap), standing=standing)
    return judge_frame(steps_taken, max_steps, down, status)


@dataclass(frozen=True)
class Verdict:
    """Whether an episode ends at a frame (``outcome`` None: fly the step), and what the driver
    says and does about it: the companion's own touchdown ``evidence`` (a note for the record),
    or why the vehicle is outside the fence (``fence_reason``: hold, then end)."""

    outcome: str | None
    evidence: Evidence | None = None
    fence_reason: str | None = None


def judge_vehicle(steps_taken: int, max_steps: int, snap: VehicleSnapshot | None, fence: Geofence | None,
                  home: HomeFrame, assist: TouchdownAssist | None = None, ground: TruthGround | None = None) -> Verdict:
    """:func:`judge_snapshot` on a vehicle the companion flies with its touchdown ``assist``
    (companion/control/touchdown.py): a touchdown is the landed state or, where the vehicle cannot
    say, the assist's evidence, or (``ground``) a SITL's truth of the first ground contact
    (companion/control/truth_contact.py); a vehicle the assist finds standing is not below the fence.
    ``snap`` None: only after the last step (a driver recovers a lost link before a step)."""
    if snap is None:
        return Verdict(judge_frame(steps_taken, max_steps, False, None))
    evidence = touchdown_evidence(snap, assist, ground)
    standing = assist is not None and assist.engaged
    outcome = judge_snapshot(steps_taken, max_steps, snap, fence, home, touched_down=evidence is not None,
                             standing=standing)
    if outcome == TOUCHDOWN and evidence is not None and evidence.note:
        return Verdict(outcome, evidence=evidence)
    if outcome == FENCE and fence is not None:
        return Verdict(outcome, fence_reason=fence.check(home.relative(snap), standing=standing).reason or "outside")
    return Verdict(outcome)


@dataclass(frozen=True)
class Score:
    """An ended episode's score. ``success`` None: unknown (no truth and no judge)."""

    success: bool | None = None
    distance_m: float | None = None
    speed_m_s: float | None = None
    true_distance_m: float | None = None

    @property
    def reward(self) -> float:
        """The paper's sparse reward: 1 for a successful touchdown, else 0."""
        return 1.0 if self.success else 0.0


def _rounded(value: float | None) -> float | None:
    return None if value is None else round(float(value), DISTANCE_DECIMALS)


def score(outcome: str, *, simulated: bool, touchdown: Mapping[str, Any] | None = None,
          estimated_distance_m: float | None = None, true_distance_m: float | None = None,
          judge_radius_m: float | None = None) -> Score:
    """The score of an episode that ended with ``outcome``.

    With a simulator (``simulated``) its ground truth judges: ``touchdown`` is its touchdown
    record (success, distance to the pad, speed), None if it has none. Without one, the distance
    is the companion's estimate (``estimated_distance_m``, given for a touchdown), with the true
    one beside it where the autopilot's SITL sends truth; success is the true distance within
    ``judge_radius_m`` where it is known (a camera sees the true pad, not the estimate's), else
    the estimate's (None: no radius, unknown). Anything but a touchdown fails wherever success is judged.
    """
    landed = outcome == TOUCHDOWN
    if simulated:
        if not landed:
            return Score(success=False)
        if touchdown is None:
            return Score()
        return Score(bool(touchdown["success"]), _rounded(touchdown["distance_to_pad_m"]),
                     _rounded(touchdown["speed_m_s"]))
    if landed and estimated_distance_m is not None:
        judged_m = estimated_distance_m if true_distance_m is None else true_distance_m
        success = None if judge_radius_m is None else judged_m <= judge_radius_m
        return Score(success, _rounded(estimated_distance_m), None, _rounded(true_distance_m))
    return Score(success=False if judge_radius_m is not None and not landed else None)


def score_estimate(outcome: str, relative_ned_m: tuple[float, float, float] | None,
                   pad_ned_m: tuple[float, float, float], *, home_known: bool, true_distance_m: float | None = None,
                   judge_radius_m: float | None = None) -> tuple[Score, list[str]]:
    """:func:`score` without a simulator, and the record's notes on how it was scored: a
    touchdown's distance estimated from the vehicle's last position relative to home
    (``relative_ned_m``; None: no telemetry; ``home_known`` False: from z = 0, no HOME_POSITION),
    ``true_distance_m`` beside it where the autopilot's SITL sends truth (companion/link/truth.py)."""
    if relative_ned_m is None or outcome != TOUCHDOWN:
        return score(outcome, simulated=False, judge_radius_m=judge_radius_m), []
    north, east, _ = relative_ned_m
    estimate = math.hypot(north - pad_ned_m[0], east - pad_ned_m[1])
    notes = ["touchdown distance estimated from the vehicle's position relative to home" if home_known else
             "touchdown distance estimated from the vehicle's position (no HOME_POSITION: from z = 0)"]
    if judge_radius_m is not None:
        notes.append("success judged by the autopilot's ground truth (the pad where the truth puts it)"
                     if true_distance_m is not None else
                     "success judged from the vehicle's reported position (the rendered pad is where it puts it)")
    return score(outcome, simulated=False, estimated_distance_m=estimate, true_distance_m=true_distance_m,
                 judge_radius_m=judge_radius_m), notes


def score_vehicle(outcome: str, snap: VehicleSnapshot | None, home: HomeFrame, pad_ned_m: tuple[float, float, float],
                  *, judge_radius_m: float | None = None,
                  simulator_truth: Callable[[], Mapping[str, Any]] | None = None) -> tuple[Score, list[str]]:
    """The one scoring rule on what a vehicle offers, and the record's notes on how: the
    simulator's touchdown (``simulator_truth``: its control surface's truth query; a failed query
    is noted and leaves the success unknown), else :func:`score_estimate` on the last snapshot
    relative to ``home``, the autopilot's truth beside it where it sends one."""
    if simulator_truth is not None:
        try:
            touchdown = simulator_truth().get("touchdown")
        except ColError as exc:
            return score(outcome, simulated=True), [f"no ground truth: {exc}"]
        return score(outcome, simulated=True, touchdown=touchdown), []
    if snap is None:
        return score_estimate(outcome, None, pad_ned_m, home_known=home.origin is not None,
                              judge_radius_m=judge_radius_m)
    return score_estimate(outcome, home.relative(snap), pad_ned_m, home_known=home.origin is not None,
                          judge_radius_m=judge_radius_m,
                          true_distance_m=truth_distance_m(snap, (pad_ned_m[0], pad_ned_m[1])))
