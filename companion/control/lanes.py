"""The batched episode core: episodes on many vehicles at once, each step on arrays.

The drivers that fly many vehicles in one process, the batched env (companion/rl/batched_env.py)
and the batched evaluation (companion/experiment/batched_eval.py), fly them through
:class:`EpisodeLanes`. Each lane is a vehicle behind a narrow port (:class:`LanePort`, on our
SITL :class:`~companion.rl.landing_lane.LandingLane`); the core keeps each lane's episode (the
frames flown, the latest telemetry, the last good observation, the limiter's memory) and does
for all lanes what the session (companion/control/session.py) does for one:

- :meth:`~EpisodeLanes.begin`: an episode's start, the limiter afresh;
- :meth:`~EpisodeLanes.judge`: whether each lane's episode ends at its frame, by the one rule of
  companion/control/outcome.py; a lane outside the geofence holds and is asked for its hold mode,
  as the session leaves the fence;
- :meth:`~EpisodeLanes.observe`: the observation vectors (companion/vision/observation_rows.py),
  the position relative to home as the session observes it, in every driver (the RL envs too);
  a vector that is not finite is not usable: the lane's last good one stands in for it (a policy
  holds that step instead);
- :meth:`~EpisodeLanes.fly`: sticks to setpoints as each lane's session would send them
  (companion/control/setpoint_rows.py; an invalid row through its lane's own mapper, repaired,
  counted and logged), holds sent as they are, then every lane's next frame;
- :meth:`~EpisodeLanes.score`: the one scoring rule on the lane's ground truth.

The stacked arithmetic is element by element, so a lane flies as it would alone, bit for bit.
The drivers keep only what is theirs: seeds and automatic resets with infos and rewards (the
vec env), the policy and the records (the evaluation). The outcome and scoring rule is called
through its module, so replacing it replaces it here too (tests/control/test_outcome.py).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping, Sequence
from typing import Any, Protocol

import numpy as np

from companion.commands import CommandMapper
from companion.config import CompanionConfig
from companion.control import outcome as outcome_rule
from companion.control.safety import Geofence
from companion.control.setpoint_rows import SetpointRows
from companion.errors import LinkError
from companion.link.home import HomeFrame
from companion.msg.observation import OBS_DIM, normalised
from companion.msg.snapshot import VehicleSnapshot
from companion.vision.observation_rows import detect_pad, pad_rows, telemetry_row
from companion.vision.perception import PadDetector

log = logging.getLogger(__name__)
START_ATTEMPTS = 3
"""Episode starts tried on a link error before giving up (the RL envs'; the session tries once)."""
ACCEPTED = 0  # MAV_RESULT_ACCEPTED


class LanePort(Protocol):
    """One vehicle as the core flies it: its home frame, geofence and mapper (repairs of its
    commands are counted per vehicle), and the frames it answers."""

    home: HomeFrame
    fence: Geofence
    mapper: CommandMapper
    image_size_px: tuple[int, int]

    def begin(self, seed: int | None, attempts: int = START_ATTEMPTS) -> VehicleSnapshot:
        """Start an episode from ``seed``: its first frame, in offboard control."""

    def velocity(self, forward_right_down_m_s: tuple[float, float, float], yaw_rate_rad_s: float) -> None:
        """Answer the frame with a body-frame velocity setpoint."""

    def hold(self) -> None:
        """Answer the frame with the zero setpoint, as it is."""

    def request_hold_mode(self) -> tuple[int, str]:
        """Ask for the autopilot's hold mode: (MAV_RESULT, why)."""

    def next_frame(self) -> VehicleSnapshot:
        """The next frame's telemetry (the home frame updated with it)."""

    def image(self) -> np.ndarray | None:
        """The latest frame's camera image (None: no camera)."""

    def ground_truth(self) -> dict[str, Any]:
        """The simulator's truth (vehicle and pad NED, touchdown)."""


def start_with_retries(begin: Callable[[int | None], VehicleSnapshot], seed: int | None,
                       attempts: int = START_ATTEMPTS) -> VehicleSnapshot:
    """``begin(seed)``, tried again on a link error (a SITL starved of CPU may miss one start)."""
    for attempt in range(1, attempts + 1):
        try:
            return begin(seed)
        except LinkError as exc:
            if attempt == attempts:
                raise
            log.warning("episode start %s failed (%s); trying again", seed, exc)
    raise AssertionError("unreachable")


def score_by_truth(outcome: str, truth: Callable[[], Mapping[str, Any]]) -> outcome_rule.Score:
    """The one scoring rule on a simulator's ground truth (asked for a touchdown only)."""
    touchdown = truth().get("touchdown") if outcome == outcome_rule.TOUCHDOWN else None
    return outcome_rule.score(outcome, simulated=True, touchdown=touchdown)


class EpisodeLanes:
    """Episodes on ``lanes`` side by side (module docstring). Rows are lane indices; every
    lane has begun an episode before it is judged, observed or flown."""

    def __init__(self, cfg: CompanionConfig, lanes: Sequence[LanePort]) -> None:
        self.lanes = list(lanes)
        self.max_steps = cfg.session.max_steps
        self.steps = [0] * len(self.lanes)
        """Frames flown in each lane's episode (the session's ``step``, the rule's steps taken)."""
        self.snaps: list[VehicleSnapshot | None] = [None] * len(self.lanes)
        """Each lane's latest telemetry."""
        self.last_obs = np.zeros((len(self.lanes), OBS_DIM), dtype=np.float32)
        self._setpoints = SetpointRows(cfg, len(self.lanes))  # each lane's limiter memory, a row each
        self._detector = PadDetector(cfg.perception)
        self._image_size = self.lanes[0].image_size_px

    def begin(self, i: int, seed: int | None, attempts: int = START_ATTEMPTS) -> VehicleSnapshot:
        """Start lane ``i``'s next episode: its first frame; the limiter starts afresh."""
        self._setpoints.forget(i)
        snap = self.snaps[i] = self.lanes[i].begin(seed, attempts)
        self.steps[i] = 0
        return snap

    def snap(self, i: int) -> VehicleSnapshot:
        """Lane ``i``'s latest telemetry."""
        snap = self.snaps[i]
        assert snap is not None, "a lane is judged, observed and flown after its episode began"
        return snap

    def judge(self, rows: Sequence[int]) -> list[str | None]:
        """Whether each lane's episode ends at its latest frame, before its step (the one rule:
        "timeout", "touchdown", "fence" or None). Outside the geofence the lane holds and asks
        for its hold mode (not a frame: the episode ends)."""
        outcomes = []
        for i in rows:
            lane = self.lanes[i]
            outcome = outcome_rule.judge_snapshot(self.steps[i], self.max_steps, self.snap(i), lane.fence, lane.home)
            if outcome == outcome_rule.FENCE:
                log.info("geofence: lane %d outside at step %d; holding and ending the episode", i, self.steps[i])
                lane.hold()
                result, why = lane.request_hold_mode()
                if result != ACCEPTED:
                    log.error("could not switch to hold: %s", why)
            outcomes.append(outcome)
        return outcomes

    def observe(self, rows: Sequence[int]) -> tuple[np.ndarray, np.ndarray]:
        """The observation vectors of these lanes' latest frames ``(len(rows), 15)`` and whether
        each is usable (finite); an unusable one is its lane's last good vector."""
        if not rows:
            return np.zeros((0, OBS_DIM), dtype=np.float32), np.zeros(0, dtype=bool)
        snaps = [self.snap(i) for i in rows]
        telemetry = np.array([telemetry_row(snap, self.lanes[i].home.relative(snap)) for i, snap in zip(rows, snaps)])
        pads = pad_rows([detect_pad(self._detector, self.lanes[i].image()) for i in rows], self._image_size)
        vectors = normalised(telemetry, pads)
        usable = np.isfinite(vectors).all(axis=1)
        index = np.asarray(rows)
        if usable.all():
            self.last_obs[index] = vectors
            return vectors, usable
        for row in np.flatnonzero(~usable).tolist():
            log.warning("lane %d step %d: unusable telemetry; its last good observation stands in",
                        rows[row], self.steps[rows[row]])
        self.last_obs[index[usable]] = vectors[usable]
        vectors[~usable] = self.last_obs[index[~usable]]
        return vectors, usable

    def fly(self, sticks: np.ndarray, rows: Sequence[int] | None = None, holding: Sequence[int] = ()) -> None:
        """One step of these lanes: each row of ``sticks`` (roll, pitch, yaw, throttle) answers
        its lane of ``rows`` (None: every lane, in order) as the lane's session sends it, the
        lanes of ``holding`` hold; then each of them flies its next frame."""
        index = range(len(self.lanes)) if rows is None else rows
        if len(index):
            setpoints = self._setpoints.setpoints(self._repaired(sticks, index), rows)
            for i, (forward, right, down, yaw_rate) in zip(index, setpoints.tolist(), strict=True):
                self.lanes[i].velocity((forward, right, down), yaw_rate)
        for i in holding:
            self.lanes[i].hold()
        for group in (index, holding):
            for i in group:
                self.snaps[i] = self.lanes[i].next_frame()
                self.steps[i] += 1

    def _repaired(self, sticks: np.ndarray, index: Sequence[int]) -> np.ndarray:
        """Rows with a non-finite or out-of-range value through their lane's mapper (repaired,
        counted, logged, as the session does); the others are valid commands already."""
        valid = np.isfinite(sticks) & (np.abs(sticks) <= 1.0)
        if valid.all():
            return sticks
        sticks = sticks.copy()
        for row in np.flatnonzero(~valid.all(axis=1)).tolist():
            sticks[row] = self.lanes[index[row]].mapper.command_from_values(sticks[row]).to_array()
        return sticks

    def score(self, i: int, outcome: str) -> outcome_rule.Score:
        """Lane ``i``'s episode, ended with ``outcome``, scored by the one rule on its truth."""
        return score_by_truth(outcome, self.lanes[i].ground_truth)
