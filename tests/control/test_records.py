"""The episode record as every driver writes it (companion/control/records.py): what it takes
from the arbiter's count, the score and the requests for help, and how it rounds."""

from __future__ import annotations

import math

from companion.control.arbiter import InterventionSummary, Phase
from companion.control.ask import AskSummary
from companion.control.outcome import Score
from companion.control.records import episode_record, supervised_steps
from companion.msg.episode import EpisodeRecord

INVOLVEMENT = InterventionSummary(steps=40, human_steps=9, recorded_steps=7, interventions=2, durations_steps=(3, 4))


def record(**changes: object) -> EpisodeRecord:
    kwargs: dict[str, object] = dict(involvement=INVOLVEMENT, control_period_s=1 / 10.5, policy_version=5,
                                     dataset_size=120, sim_time_s=3.80951, wall_time_s=1.23456, notes=["a", "b"],
                                     ask=None, supervised_steps=40, ask_threshold=None)
    kwargs.update(changes)
    return episode_record(3, Phase.INTERVENTION, 7, 40, "touchdown", Score(True, 0.25, 0.4, 0.3),
                                    **kwargs)  # type: ignore[arg-type]


def test_the_record_carries_the_involvement_the_score_and_rounded_times() -> None:
    r = record()
    assert (r.episode, r.phase, r.seed, r.steps, r.outcome) == (3, "intervention", 7, 40, "touchdown")
    assert (r.human_samples, r.interventions) == (7, 2)
    assert r.intervention_durations_s == (0.286, 0.381)  # 3 and 4 steps at 10.5 Hz
    assert r.intervention_s == 0.667
    assert (r.success, r.touchdown_distance_m, r.touchdown_speed_m_s, r.true_touchdown_distance_m) == (True, 0.25, 0.4, 0.3)
    assert (r.policy_version, r.dataset_size, r.sim_time_s, r.wall_time_s) == (5, 120, 3.81, 1.235)
    assert r.notes == ("a", "b")
    assert (r.requests, r.requests_unanswered, r.supervised_steps, r.ask_threshold) == (0, 0, 40, None)


def test_the_requests_for_help_and_their_threshold() -> None:
    ask = AskSummary(requests=3, answered=2, unanswered=1, engaged_steps=12, response_steps=(2, 5))
    r = record(ask=ask, supervised_steps=12, ask_threshold=0.0123456789)
    assert (r.requests, r.requests_unanswered, r.supervised_steps, r.ask_threshold) == (3, 1, 12, 0.01234568)
    assert record(ask=ask, ask_threshold=math.inf).ask_threshold is None  # not calibrated yet: none


def test_the_steps_a_person_had_to_watch() -> None:
    assert supervised_steps(Phase.AUTONOMOUS, 80, 12) == 0
    assert supervised_steps(Phase.DEMONSTRATION, 80, None) == 80
    assert supervised_steps(Phase.INTERVENTION, 80, None) == 80  # watching throughout
    assert supervised_steps(Phase.INTERVENTION, 80, 12) == 12  # watching only when asked
