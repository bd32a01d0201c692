"""The episode record: one JSON line per episode (runs/<run>/episodes.jsonl); built by
companion/control/records.py's :func:`~companion.control.records.episode_record`."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any


@dataclass(frozen=True)
class EpisodeRecord:
    """One JSON line per episode (runs/<run>/episodes.jsonl)."""

    episode: int
    phase: str
    seed: int | None
    steps: int
    human_samples: int
    interventions: int
    intervention_s: float
    intervention_durations_s: tuple[float, ...]
    outcome: str  # touchdown | timeout | fence | link_lost | error | stopped (by the operator)
    success: bool | None
    touchdown_distance_m: float | None
    touchdown_speed_m_s: float | None
    policy_version: int | None
    dataset_size: int
    sim_time_s: float
    wall_time_s: float
    notes: tuple[str, ...] = field(default_factory=tuple)
    loss_all: float | None = None
    """After the episode (and the learner's between-episode updates): the policy's MSE on
    every human sample, and on the intervention samples alone (None: none recorded)."""
    loss_intervention: float | None = None
    requests: int = 0
    """Requests for help in this episode (``[companion.ask]``), and how many went unanswered."""
    requests_unanswered: int = 0
    supervised_steps: int = 0
    """Steps the person had to watch: every step of a demonstration, and of an intervention
    episode flown by a person who watches throughout; for a person who watches only when
    asked, the steps from each request until they handed back."""
    ask_threshold: float | None = None
    """The disagreement threshold of this episode (None: not asking)."""
    true_touchdown_distance_m: float | None = None
    """Without a simulator: the touchdown's true distance from the pad where the autopilot's SITL
    sends its true position (companion/link/truth.py); the estimate's is touchdown_distance_m."""

    def to_json_dict(self) -> dict[str, Any]:
        return asdict(self)
