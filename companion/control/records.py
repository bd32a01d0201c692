"""What an episode tells the outside: each step as a watcher sees it (:class:`StepView`) and
the episode's record (:class:`EpisodeRecord`, one JSON line of ``episodes.jsonl``). Every driver of
an episode writes the same record (companion/experiment/batched_eval.py writes it without the
wall time); a console, a video and the reports read them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TypeVar

from companion.control.arbiter import Decision, InterventionSummary, Phase
from companion.control.ask import AskSummary
from companion.control.outcome import Score
from companion.msg.episode import EpisodeRecord
from companion.msg.observation import Observation
from companion.msg.setpoint import VelocitySetpoint

R = TypeVar("R", bound=EpisodeRecord)


@dataclass(frozen=True)
class StepView:
    """What one control step saw and did, for someone watching (a console, a video)."""

    episode: int
    step: int
    phase: Phase
    observation: Observation
    decision: Decision
    setpoint: VelocitySetpoint
    policy_version: int | None
    human_override: bool
    human_hold: bool
    frame_number: int | None = None
    """The camera frame the observation's pad was detected in (None: none)."""



def supervised_steps(phase: Phase, steps: int, engaged_steps: int | None) -> int:
    """The steps of an episode the person had to watch (:attr:`EpisodeRecord.supervised_steps`):
    none of an autonomous one; ``engaged_steps`` for a person who watches only when asked (the
    steps from each request until they handed back); else every step (None: they watch throughout)."""
    if phase is Phase.AUTONOMOUS:
        return 0
    return steps if engaged_steps is None else engaged_steps


def episode_record(episode: int, phase: Phase, seed: int | None, steps: int, outcome: str, result: Score, *,
                   involvement: InterventionSummary, control_period_s: float, policy_version: int | None,
                   dataset_size: int, sim_time_s: float, wall_time_s: float, notes: list[str],
                   ask: AskSummary | None, supervised_steps: int, ask_threshold: float | None,
                   record_type: type[R] = EpisodeRecord) -> R:  # type: ignore[assignment]
    """The record (``record_type``: EpisodeRecord or a driver's own kind of it) of an ended episode, scored ``result`` (companion/control/outcome.py): the
    person's involvement as the arbiter counted it, the requests for help (``ask`` None: not
    asking; an ``ask_threshold`` that is not finite is none), times rounded to the millisecond."""
    durations = involvement.durations_s(control_period_s)
    return record_type(
        episode=episode, phase=phase.value, seed=seed, steps=steps,
        human_samples=involvement.recorded_steps, interventions=involvement.interventions,
        intervention_s=round(sum(durations), 3), intervention_durations_s=tuple(round(d, 3) for d in durations),
        outcome=outcome, success=result.success,
        touchdown_distance_m=result.distance_m, touchdown_speed_m_s=result.speed_m_s,
        policy_version=policy_version, dataset_size=dataset_size,
        sim_time_s=round(sim_time_s, 3), wall_time_s=round(wall_time_s, 3), notes=tuple(notes),
        requests=ask.requests if ask else 0, requests_unanswered=ask.unanswered if ask else 0,
        supervised_steps=supervised_steps,
        true_touchdown_distance_m=result.true_distance_m,
        ask_threshold=None if ask_threshold is None or not math.isfinite(ask_threshold) else round(ask_threshold, 8),
    )
