"""Batched evaluation: the final policy on the held-out starts, flown by the batched episode core
(:class:`~companion.control.lanes.EpisodeLanes`) on session-free lanes in one process, exactly
the episodes of the session's evaluation.

Why: evaluation is most of a grid's episodes (19,200 of the paper grid's 20,544), and the
in-process session still composes, packs and folds every MAVLink message and runs the link,
observer and episode loop around each step; the lanes fly the same vehicle, camera and detector
without them (``bench/experiment_speed.py``: ``eval_batched_profile``).

The session's evaluation (``evaluate_checkpoint`` -> ``run_episodes(pilot="none",
condition="eval", lockstep=True)``): episode ``k``, seed ``eval_seed + k``, phase AUTONOMOUS, in
a SITL whose world seed is ``eval_seed``; the checkpoint published by a ``Learner`` that never
trains. The core flies each of its steps as the session does (the start without a retry, the one
outcome rule, the fence's hold counted as a step, the observation from home, a hold on unusable
telemetry, the setpoint arithmetic, the one scoring rule); here are the policy, asked by the very
call the session makes (``disagreement``) one vector at a time (gemm and gemv may round apart),
and the session's record. ``lanes`` starts fly side by side (:data:`DEFAULT_LANES`): an episode
depends on its seed, not on its lane or what flew before (every reset restarts the SITL's
vehicle, JSBSim, disturbance and telemetry phase on a whole second of its clock); only the
driving pad's position, computed from that clock, can round apart in the last bit (1e-16 m),
and the records, rounded as the session rounds them, come out the same
(``tests/experiment/test_batched_eval.py``; committed trials rerun byte for byte).

:class:`EvalEpisode` is the session's record without its wall time (lanes interleave episodes:
it is left out rather than made up). Not flown here (:func:`why_not_batched`; the session flies
it): the touchdown assist, asking for help, a camera other than the SITL's, a frame marker other
than SYSTEM_TIME, a SITL personality other than PX4's. An episode that cannot start raises
:class:`~companion.errors.SessionOnly` (the session records an "error" episode and goes on).
"""

from __future__ import annotations

import json
import math
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from companion.app import RunOptions
from companion.config import CompanionConfig
from companion.control import outcome as outcome_rule
from companion.control.arbiter import Arbiter, Phase
from companion.control.lanes import EpisodeLanes
from companion.control.records import episode_record
from companion.errors import ColError, SessionOnly
from companion.inprocess import sitl_config_for
from companion.learning.checkpoint import load_checkpoint
from companion.learning.dataset import HumanDataset
from companion.learning.ensemble import disagreement
from companion.learning.learner import Learner
from companion.learning.snapshot import PolicySnapshot
from companion.msg.episode import EpisodeRecord
from companion.rl.landing_lane import open_lanes
from companion.rl.landing_task import DESCENT_THROTTLE
from sitl.config import SitlConfig, load_sitl_config

DEFAULT_LANES = 1
"""Starts in flight at once. More lanes only share the few numpy calls of a step's arithmetic
(a few percent of a step), while each lane holds its own vehicle, renderer buffers and episode
noise field (1.8 MB): 2, 4 and 8 lanes took 3-12 % more CPU per step than one
(``eval_batched_lanes`` in bench/results/experiment_speed-batched-eval-2026-12-02.json). The
episodes are the same with any number."""
SESSION_ONLY_FIELDS = ("wall_time_s",)
"""Fields of the session's episode record the batched evaluation cannot give (module docstring)."""
ACTION_DIMS = 4  # the policy's sticks, all four (the lane keeps this only as an attribute)


@dataclass(frozen=True)
class EvalEpisode(EpisodeRecord):
    """One evaluation episode as the session records it; its wall time unknown (NaN)."""

    wall_time_s: float = math.nan

    def to_json_dict(self) -> dict[str, Any]:
        """The session's JSON line, its keys in its order, without :data:`SESSION_ONLY_FIELDS`."""
        return {k: v for k, v in super().to_json_dict().items() if k not in SESSION_ONLY_FIELDS}


@dataclass
class BatchedEvaluation:
    """What ``evaluate_checkpoint`` gives a trial's result: the records, in episode order."""

    records: list[EvalEpisode] = field(default_factory=list)

    @property
    def successes(self) -> int:
        return sum(1 for r in self.records if r.success)


@dataclass
class _Flight:
    """One lane's episode in flight: what the session's loop keeps for it besides the core."""

    episode: int
    seed: int
    t0_ms: int
    version: int | None = None


def why_not_batched(cfg: CompanionConfig, config_path: Path | None) -> str | None:
    """Why this evaluation must fly through the session (None: the batched one flies it)."""
    if cfg.session.policy_pad_ned_m is not None:
        return "the policy's frame is moved ([companion.session] policy_pad_ned_m)"
    if cfg.landing.touchdown_assist:
        return "the touchdown assist ([companion.landing] touchdown_assist) is on"
    if cfg.ask.enabled:
        return "asking for help ([companion.ask]) is on"
    if cfg.perception.camera.strip() != "auto":
        return f"the camera is {cfg.perception.camera!r}, not the SITL's (\"auto\")"
    if cfg.link.frame_marker != "SYSTEM_TIME":
        return f"the frame marker is {cfg.link.frame_marker}, not SYSTEM_TIME"
    autopilot = load_sitl_config(config_path).personality.autopilot
    if autopilot != "px4":
        return f"the SITL flies the {autopilot} personality, not PX4's"
    return None


def eval_policy(cfg: CompanionConfig, checkpoint: Path) -> PolicySnapshot:
    """The policy the session's evaluation flies: the checkpoint as ``run_episodes`` loads it
    (CheckpointError if it is missing or unfit), published by a Learner that never trains."""
    initial, _ = load_checkpoint(checkpoint)
    return Learner(cfg.learner, HumanDataset(None), initial=initial).latest_snapshot


def evaluate_batched(cfg: CompanionConfig, checkpoint: Path, first_seed: int, episodes: int,
                     config_path: Path | None, lanes: int | None = None) -> BatchedEvaluation:
    """The session's evaluation of ``checkpoint`` on seeds ``first_seed ...`` (module docstring),
    ``lanes`` starts at a time (None: :data:`DEFAULT_LANES`)."""
    lanes = DEFAULT_LANES if lanes is None else lanes
    if episodes < 1 or lanes < 1:
        raise ValueError(f"episodes and lanes must be at least 1, got {episodes} and {lanes}")
    reason = why_not_batched(cfg, config_path)
    if reason is not None:
        raise SessionOnly(f"the batched evaluation cannot fly this: {reason}; evaluate through the session")
    snapshot = eval_policy(cfg, checkpoint)
    sitl_cfg = sitl_config_for(cfg, RunOptions(config_path=config_path, seed=first_seed))
    with BatchedEvaluator(cfg, snapshot, sitl_cfg, min(lanes, episodes)) as evaluator:
        records = evaluator.run((k, first_seed + k) for k in range(episodes))
    return BatchedEvaluation(records)


def write_records(records: Iterable[EvalEpisode], path: Path) -> None:
    """``eval_episodes.jsonl``: one JSON line per episode, as the session writes them."""
    with path.open("w") as fh:
        for record in records:
            fh.write(json.dumps(record.to_json_dict()) + "\n")


class BatchedEvaluator:
    """Lanes that fly the session's evaluation episodes side by side (module docstring)."""

    def __init__(self, cfg: CompanionConfig, snapshot: PolicySnapshot, sitl_cfg: SitlConfig, lanes: int) -> None:
        self.snapshot = snapshot
        self.period_s = 1.0 / cfg.session.control_rate_hz
        self._stack, self.lanes = open_lanes(cfg, sitl_cfg, lanes, ACTION_DIMS, DESCENT_THROTTLE)
        self.core = EpisodeLanes(cfg, self.lanes)

    def __enter__(self) -> BatchedEvaluator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """OpenCV gets its threads back; safe to call twice."""
        self._stack.close()

    def run(self, starts: Iterable[tuple[int, int]]) -> list[EvalEpisode]:
        """Fly every (episode number, seed); a lane takes the next start when its episode ends.
        The records in episode order."""
        todo = deque(starts)
        flights: dict[int, _Flight] = {}
        for i in range(len(self.lanes)):
            self._next(i, todo, flights)
        records = []
        while flights:
            rows = list(flights)
            ended = [(i, outcome) for i, outcome in zip(rows, self.core.judge(rows), strict=True) if outcome]
            for i, outcome in ended:
                records.append(self._record(i, flights.pop(i), outcome))
            self._step(flights)
            for i, _ in ended:
                self._next(i, todo, flights)
        return sorted(records, key=lambda r: r.episode)

    def _next(self, i: int, todo: deque[tuple[int, int]], flights: dict[int, _Flight]) -> None:
        """Start the next episode on lane ``i``, if any is left (``EpisodeRunner.run``'s start)."""
        if not todo:
            return
        episode, seed = todo.popleft()
        try:
            first = self.core.begin(i, seed, attempts=1)
        except ColError as exc:
            raise SessionOnly(f"evaluation episode {episode} (seed {seed}) could not start ({exc}): the "
                              "session records it as an error episode, the batched evaluation does not") from exc
        flights[i] = _Flight(episode, seed, first.time_boot_ms)

    def _step(self, flights: dict[int, _Flight]) -> None:
        """One control step of every flight: the policy's command, or a hold on unusable telemetry."""
        rows = list(flights)
        vectors, usable = self.core.observe(rows)
        good = usable.tolist()
        acting = [i for i, ok in zip(rows, good, strict=True) if ok]
        sticks = np.empty((len(acting), 4))
        for row, vector in enumerate(vectors[usable]):
            sticks[row], _ = disagreement(self.snapshot, vector.copy())  # one vector, as the session
        for i, ok in zip(rows, good, strict=True):
            flights[i].version = self.snapshot.version if ok else None
        self.core.fly(sticks, acting, holding=[i for i, ok in zip(rows, good, strict=True) if not ok])

    def _record(self, i: int, flight: _Flight, outcome: str) -> EvalEpisode:
        """``EpisodeRunner._record`` with a simulator, for an autonomous episode: the one rule.
        A fence exit's hold answered its frame: a step, as the session counts it (no policy)."""
        fence = outcome == outcome_rule.FENCE
        return episode_record(
            flight.episode, Phase.AUTONOMOUS, flight.seed, self.core.steps[i] + fence, outcome,
            self.core.score(i, outcome), involvement=Arbiter().summary(), control_period_s=self.period_s,
            policy_version=None if fence else flight.version, dataset_size=0,
            sim_time_s=(self.core.snap(i).time_boot_ms - flight.t0_ms) / 1000.0, wall_time_s=math.nan, notes=[],
            ask=None, supervised_steps=0, ask_threshold=None, record_type=EvalEpisode)
