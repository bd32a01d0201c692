"""Batched evaluation: the final policy on the held-out starts through the session-free lanes of
the batched env, in one process, flying exactly the episodes of the session's evaluation.

Why: evaluation is most of a grid's episodes (19,200 of the paper grid's 20,544). The in-process
session (:mod:`companion.inprocess`) still composes, packs and folds every MAVLink
message and runs the link, observer and episode loop around each step; the lanes of
:mod:`companion.rl.batched_env` (:class:`~companion.rl.landing_lane.LandingLane`) fly the same
vehicle, camera and detector without them. ``lanes`` starts fly side by side, a lane taking the
next start when its episode ends (one lane by default: :data:`DEFAULT_LANES`). What is left of a
step is mostly the SITL's own work, which both paths do (``bench/experiment_speed.py``:
``eval_batched_profile``).

What the session's evaluation is (``evaluate_checkpoint`` -> ``run_episodes(pilot="none",
condition="eval", lockstep=True, vehicle=inprocess_vehicle)``): episode ``k`` of a fresh run
folder, seed ``eval_seed + k``, phase AUTONOMOUS, in a SITL whose world seed is ``eval_seed``;
the policy is the checkpoint loaded by ``load_checkpoint`` and published by a ``Learner`` that
never trains (``_Frozen``), so an ensemble stays an ensemble and the process has one BLAS thread.
Every control step of ``EpisodeRunner._fly`` maps to a batched step of one lane as follows:

=====================================================  ===============================================
session (``EpisodeRunner``)                            batched (:class:`BatchedEvaluator`)
=====================================================  ===============================================
``run``: limiter reset, ``starter.start(seed)``:       ``LandingLane.begin(seed, attempts=1)``: the
reset, frames until in the air, one HOLD, OFFBOARD     same frames and requests; the limiter row forgot
each frame judged before its step (time, touchdown,    the very same :func:`~companion.control.outcome.
fence): :mod:`companion.control.outcome`               judge_snapshot`; a fence exit sends HOLD and the
                                                       hold mode and counts as a step, as there
``observer.observe(...).to_vector()``, the position    :mod:`companion.vision.observation_rows` on the
relative to home                                       lane's snapshot and home; a vector that is not
                                                       finite holds, version None, as there
``disagreement(snapshot, vector)``                     the very same call, one vector at a time (no
                                                       stacked matmul: gemm and gemv may round apart)
``mapper.command_from_values(action)``                 valid rows as they are; a row with a non-finite
                                                       or out-of-range value through the lane's mapper
``limiter.apply(mapper.to_setpoint(command))``, the    :class:`~companion.control.setpoint_rows.
link's limits                                          SetpointRows`, each lane's memory its own
the next lockstep frame                                ``LandingLane.next_frame``
the record's score: :func:`~companion.control.         the same function on the lane's ``truth()``
outcome.score` on the simulator's truth                (the same JSON round trip)
=====================================================  ===============================================

The 2-action ``LandingEnv`` holds the throttle at a constant descent and turns no yaw; here the
policy's four outputs (roll, pitch, yaw, throttle) are the sticks, as in the session. The
observation normalisation in a checkpoint is the snapshot's own (inside ``act``); nothing scales
actions after ``tanh``.

An episode depends on its seed, not on which lane flies it or what flew before: at every reset
the SITL restarts its vehicle, controller, JSBSim instance, disturbance and telemetry phase, on a
whole second of its clock. One thing still reads that clock: the driving pad's position is its
velocity times the time since the episode's start, computed from the clock, so between a lane and
the session it can round apart in the last bit (1e-16 m), and a vehicle standing on the moving
roof carries that into its state; the flight itself is bit for bit the same for the same
setpoints. The records, rounded as the session rounds them, come out the same
(``tests/experiment/test_batched_eval.py``: 1, 2 and 3 lanes at level 0.2; the held-out starts of
committed trials record for record; committed trials rerun byte for byte, bench/README.md).

Records (``eval_episodes.jsonl``): :class:`EvalEpisode` has every field of the session's
:class:`~companion.control.records.EpisodeRecord` with the same values, in the same order, but
``wall_time_s``: lanes fly episodes interleaved, and what one took of the machine's time is no
property of the episode; it is left out rather than made up.

Not flown here (:func:`why_not_batched` says so, and ``evaluate_checkpoint`` takes the session):
the touchdown assist (``[companion.landing]``; experiment files turn it off), asking for help,
a camera other than the SITL's, a frame marker other than SYSTEM_TIME, a SITL personality other
than PX4's. An episode that cannot start (the session records an "error" episode and goes on)
raises :class:`~companion.errors.SessionOnly`, and the session evaluates instead.
"""

from __future__ import annotations

import contextlib
import json
import logging
from collections import deque
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from companion.app import RunOptions
from companion.config import CompanionConfig
from companion.control import outcome as outcome_rule
from companion.control.arbiter import Phase
from companion.control.records import EpisodeRecord
from companion.control.setpoint_rows import SetpointRows
from companion.errors import ColError, SessionOnly
from companion.inprocess import one_opencv_thread, sitl_config_for
from companion.learning.checkpoint import load_checkpoint
from companion.learning.dataset import HumanDataset
from companion.learning.ensemble import disagreement
from companion.learning.learner import Learner
from companion.learning.snapshot import PolicySnapshot
from companion.link.base import VehicleSnapshot
from companion.rl.gym_env import DESCENT_THROTTLE
from companion.rl.landing_lane import LandingLane
from companion.vision.observation import normalised
from companion.vision.observation_rows import detect_pad, pad_rows, telemetry_row
from companion.vision.perception import PadDetector
from sitl.config import SitlConfig, load_sitl_config

log = logging.getLogger(__name__)
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
class EvalEpisode:
    """One evaluation episode as the session records it, without its wall time."""

    episode: int
    seed: int
    steps: int
    outcome: str
    success: bool | None
    touchdown_distance_m: float | None
    touchdown_speed_m_s: float | None
    policy_version: int | None
    sim_time_s: float
    phase: str = Phase.AUTONOMOUS.value
    human_samples: int = 0
    interventions: int = 0
    intervention_s: float = 0  # the session's round(sum(()), 3): the int 0
    intervention_durations_s: tuple[float, ...] = ()
    dataset_size: int = 0
    notes: tuple[str, ...] = ()
    loss_all: float | None = None
    loss_intervention: float | None = None
    requests: int = 0
    requests_unanswered: int = 0
    supervised_steps: int = 0
    ask_threshold: float | None = None
    true_touchdown_distance_m: float | None = None

    def to_json_dict(self) -> dict[str, Any]:
        """The session's JSON line (``EpisodeRecord.to_json_dict``), its keys in its order,
        without :data:`SESSION_ONLY_FIELDS`."""
        values = asdict(self)
        return {f.name: values[f.name] for f in fields(EpisodeRecord) if f.name not in SESSION_ONLY_FIELDS}


@dataclass
class BatchedEvaluation:
    """What ``evaluate_checkpoint`` gives a trial's result: the records, in episode order."""

    records: list[EvalEpisode] = field(default_factory=list)

    @property
    def successes(self) -> int:
        return sum(1 for r in self.records if r.success)


@dataclass
class _Flight:
    """One lane's episode in flight: what the session's loop keeps for it."""

    episode: int
    seed: int
    t0_ms: int
    step: int = 0
    """The session loop's ``step``: frames flown since the first."""
    steps: int = 0
    """What the record's ``steps`` would be if the episode ended now."""
    version: int | None = None


def why_not_batched(cfg: CompanionConfig, config_path: Path | None) -> str | None:
    """Why this evaluation must fly through the session (None: the batched one flies it)."""
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
        self.max_steps = cfg.session.max_steps
        self.period_s = 1.0 / cfg.session.control_rate_hz
        self._stack = contextlib.ExitStack()
        self._stack.enter_context(one_opencv_thread())  # as the in-process SITL renders
        try:
            self.lanes = [LandingLane(cfg, sitl_cfg, ACTION_DIMS, DESCENT_THROTTLE) for _ in range(lanes)]
        except BaseException:
            self._stack.close()
            raise
        self._setpoint_rows = SetpointRows(cfg, lanes)  # each lane's mapper and limiter; repairs stay per lane
        self._detector = PadDetector(cfg.perception)
        camera = sitl_cfg.camera
        self._image_size = (camera.width_px, camera.height_px)

    def __enter__(self) -> BatchedEvaluator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """OpenCV gets its threads back; safe to call twice."""
        self._stack.close()

    # ----- episodes -----------------------------------------------------------------------------
    def run(self, starts: Iterable[tuple[int, int]]) -> list[EvalEpisode]:
        """Fly every (episode number, seed); a lane takes the next start when its episode ends.
        The records in episode order."""
        todo = deque(starts)
        flights: dict[int, _Flight] = {}
        for i in range(len(self.lanes)):
            self._next(i, todo, flights)
        records = []
        while flights:
            for i, record in self._step(flights):
                records.append(record)
                del flights[i]
                self._next(i, todo, flights)
        return sorted(records, key=lambda r: r.episode)

    def _next(self, i: int, todo: deque[tuple[int, int]], flights: dict[int, _Flight]) -> None:
        """Start the next episode on lane ``i``, if any is left (``EpisodeRunner.run``'s start)."""
        if not todo:
            return
        episode, seed = todo.popleft()
        try:
            first = self.lanes[i].begin(seed, attempts=1)
        except ColError as exc:
            raise SessionOnly(f"evaluation episode {episode} (seed {seed}) could not start ({exc}): the "
                              "session records it as an error episode, the batched evaluation does not") from exc
        flights[i] = _Flight(episode, seed, first.time_boot_ms)
        self._setpoint_rows.forget(i)  # the session's limiter starts afresh

    def _step(self, flights: dict[int, _Flight]) -> list[tuple[int, EvalEpisode]]:
        """One control step of every flight; the episodes that ended, by lane (judged by the one
        rule of companion/control/outcome.py before the step, as the session judges)."""
        ended: list[tuple[int, EvalEpisode]] = []
        flying = []
        for i, flight in flights.items():
            lane = self.lanes[i]
            outcome = outcome_rule.judge_snapshot(flight.step, self.max_steps, self._snap(i), lane.fence, lane.home)
            if outcome == outcome_rule.FENCE:
                ended.append((i, self._fence(i, flight)))
            elif outcome is not None:
                ended.append((i, self._record(i, flight, outcome)))
            else:
                flying.append(i)
        vectors = self._observations(flying)
        acting, answered = [], []
        for i, vector in zip(flying, vectors, strict=True):
            flight = flights[i]
            flight.steps = flight.step + 1
            if not np.isfinite(vector).all():
                log.warning("step %d: unusable telemetry (observation %s); holding", flight.step, vector)
                flight.version = None
                self.lanes[i].hold()
                answered.append(i)
            else:
                acting.append((i, vector))
        self._act(flights, acting)
        for i in [i for i, _ in acting] + answered:
            self.lanes[i].next_frame()
            flights[i].step += 1
        return ended

    def _fence(self, i: int, flight: _Flight) -> EvalEpisode:
        """Outside the geofence: HOLD and the hold mode, as the session asks them, then the end
        (the hold answers the frame: it counts as a step, as in the session)."""
        lane = self.lanes[i]
        log.warning("geofence: outside at step %d of evaluation episode %d; holding and ending the episode",
                    flight.step, flight.episode)
        lane.hold()
        result, why = lane.sitl.request_mode(lane.dialect.hold_mode)
        if result != 0:
            log.error("could not switch to hold: %s", why)
        flight.steps, flight.version = flight.step + 1, None
        return self._record(i, flight, outcome_rule.FENCE)

    def _record(self, i: int, flight: _Flight, outcome: str) -> EvalEpisode:
        """``EpisodeRunner._record`` with a simulator, for an autonomous episode: the one rule."""
        touchdown = self.lanes[i].sitl.truth().get("touchdown") if outcome == outcome_rule.TOUCHDOWN else None
        result = outcome_rule.score(outcome, simulated=True, touchdown=touchdown)
        sim_s = (self._snap(i).time_boot_ms - flight.t0_ms) / 1000.0
        return EvalEpisode(episode=flight.episode, seed=flight.seed, steps=flight.steps, outcome=outcome,
                           success=result.success, touchdown_distance_m=result.distance_m,
                           touchdown_speed_m_s=result.speed_m_s, policy_version=flight.version,
                           sim_time_s=round(sim_s, 3))

    # ----- one step's arithmetic ------------------------------------------------------------------
    def _snap(self, i: int) -> VehicleSnapshot:
        snap = self.lanes[i].sitl.reported
        assert snap is not None  # a lane is connected before it flies
        return snap

    def _relative(self, i: int) -> tuple[float, float, float]:
        """The position the session observes and fences: relative to the lane's home."""
        return self.lanes[i].home.relative(self._snap(i))

    def _observations(self, indices: Sequence[int]) -> np.ndarray:
        """The session's observation vectors of these lanes' latest frames, unchecked."""
        telemetry = np.array([telemetry_row(self._snap(i), self._relative(i)) for i in indices]).reshape(-1, 12)
        pads = pad_rows([detect_pad(self._detector, self.lanes[i].sitl.image()) for i in indices], self._image_size)
        return normalised(telemetry, pads)

    def _act(self, flights: dict[int, _Flight], acting: Sequence[tuple[int, np.ndarray]]) -> None:
        """The policy's command for each acting lane, mapped, limited and sent as the session does."""
        if not acting:
            return
        sticks = np.empty((len(acting), 4))
        for row, (i, vector) in enumerate(acting):
            action, _ = disagreement(self.snapshot, vector.copy())  # one vector, as the session
            flights[i].version = self.snapshot.version
            sticks[row] = action
            if not (np.isfinite(sticks[row]).all() and (np.abs(sticks[row]) <= 1.0).all()):
                sticks[row] = self.lanes[i].mapper.command_from_values(action).to_array()  # repaired, counted, logged
        lanes = [i for i, _ in acting]
        setpoints = self._setpoint_rows.setpoints(sticks, lanes)
        for i, (forward, right, down, yaw_rate) in zip(lanes, setpoints.tolist(), strict=True):
            self.lanes[i].velocity((forward, right, down), yaw_rate)
