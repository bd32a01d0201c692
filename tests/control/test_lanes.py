"""The batched episode core (companion/control/lanes.py) on fake vehicle ports: it judges by the
one rule and holds at the fence, observes from home or as reported and flags unusable telemetry,
sends each lane what its session would send (repairs by the lane's own mapper, holds as they
are), counts the frames flown and scores by the truth. Its drivers are checked against the
session and the single env in tests/rl/test_batched_env.py and tests/experiment/test_batched_eval.py."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np
import pytest

from companion.commands import CommandMapper
from companion.config import CompanionConfig
from companion.control import outcome
from companion.control.lanes import EpisodeLanes, score_by_truth, start_with_retries
from companion.control.safety import Geofence, SetpointLimiter
from companion.errors import LinkError
from companion.link.home import HomeFrame
from companion.msg.observation import normalised
from companion.msg.snapshot import VehicleSnapshot
from companion.vision.observation_rows import pad_rows, telemetry_row

CFG = CompanionConfig()
START = VehicleSnapshot(0.0, 1000, 1000, 1, "PX4", True, "OFFBOARD", "IN_AIR", (0.5, -0.5, -4.0), (0.1, 0.0, -0.2),
                        (0.01, 0.02, 1.0), (0.0, 0.0, 0.0), 0.0, True, True, home_ned_m=(0.0, 0.0, -0.5))
TRUTH = {"success": True, "distance_to_pad_m": 0.2, "speed_m_s": 0.3}


class FakeLane:
    """A vehicle port whose frames are given: what it was sent is kept."""

    image_size_px = (320, 240)

    def __init__(self, frames: list[VehicleSnapshot] | None = None) -> None:
        self.home, self.fence, self.mapper = HomeFrame(), Geofence.from_config(CFG.safety), CommandMapper(CFG.commands)
        self.frames = list(frames or [])
        self.sent: list[Any] = []
        self.truth_asked = 0

    def begin(self, seed: int | None, attempts: int = 3) -> VehicleSnapshot:
        self.home.update(START)
        return START

    def velocity(self, forward_right_down_m_s: tuple[float, float, float], yaw_rate_rad_s: float) -> None:
        self.sent.append((*forward_right_down_m_s, yaw_rate_rad_s))

    def hold(self) -> None:
        self.sent.append("hold")

    def request_hold_mode(self) -> tuple[int, str]:
        self.sent.append("hold mode")
        return 0, ""

    def next_frame(self) -> VehicleSnapshot:
        snap = self.frames.pop(0) if self.frames else START
        self.home.update(snap)
        return snap

    def image(self) -> np.ndarray | None:
        return None

    def ground_truth(self) -> dict[str, Any]:
        self.truth_asked += 1
        return {"touchdown": TRUTH}


def _core(*lanes: FakeLane) -> EpisodeLanes:
    core = EpisodeLanes(CFG, lanes)
    for i in range(len(lanes)):
        core.begin(i, 100 + i)
    return core


def test_each_lane_is_judged_by_the_one_rule_and_holds_outside_the_fence() -> None:
    away = dataclasses.replace(START, position_ned_m=(50.0, 0.0, -4.0))
    inside, outside = FakeLane(), FakeLane([away])
    core = _core(inside, outside)
    assert core.judge([0, 1]) == [None, None]  # the first frames: inside both
    core.fly(np.zeros((2, 4)))
    assert core.steps == [1, 1]
    assert core.judge([0, 1]) == [None, outcome.FENCE]
    assert outside.sent[-2:] == ["hold", "hold mode"] and "hold" not in inside.sent
    core.steps[0] = CFG.session.max_steps
    assert core.judge([0]) == [outcome.TIMEOUT]


def test_observations_from_home_and_unusable_ones_flagged() -> None:
    lane = FakeLane([dataclasses.replace(START, velocity_ned_m_s=(math.nan, 0.0, 0.0))])
    core = _core(lane)
    vectors, usable = core.observe([0])
    assert usable.tolist() == [True]
    from_home = vectors[0].copy()
    reported = normalised(np.array([telemetry_row(START)]), pad_rows([None], lane.image_size_px))  # as sent
    assert from_home[:2].tolist() == reported[0, :2].tolist() and from_home[2] != reported[0, 2]  # home 0.5 m up
    core.fly(np.zeros((1, 4)))
    vectors, usable = core.observe([0])
    assert usable.tolist() == [False] and np.array_equal(vectors[0], from_home)  # the last good one stands in
    assert core.observe([])[0].shape == (0, 15)


def test_each_lane_is_sent_what_its_session_sends(rng: np.random.Generator) -> None:
    lanes = [FakeLane(), FakeLane(), FakeLane()]
    core = _core(*lanes)
    limiters = [SetpointLimiter(CFG.commands, CFG.safety) for _ in lanes]
    mapper = CommandMapper(CFG.commands)
    for _ in range(5):
        sticks = rng.uniform(-1.2, 1.2, (2, 4))
        sticks[0, 1] = np.nan
        core.fly(sticks, rows=[2, 0], holding=[1])
        for row, i in enumerate((2, 0)):
            command = mapper.command_from_values(sticks[row])
            expected = limiters[i].apply(mapper.to_setpoint(command), 1.0 / CFG.session.control_rate_hz)
            assert lanes[i].sent[-1] == expected.as_tuple()  # bit for bit
        assert lanes[1].sent[-1] == "hold"
    assert core.steps == [5, 5, 5]
    assert lanes[2].mapper.counts.non_finite_axes == 5 and lanes[0].mapper.counts.non_finite_axes == 0


def test_scored_by_the_truth_which_is_asked_for_a_touchdown_only() -> None:
    lane = FakeLane()
    core = _core(lane)
    assert core.score(0, outcome.TIMEOUT) == outcome.Score(success=False) and lane.truth_asked == 0
    assert core.score(0, outcome.TOUCHDOWN) == outcome.Score(True, 0.2, 0.3) and lane.truth_asked == 1
    assert score_by_truth(outcome.TOUCHDOWN, lambda: {}) == outcome.Score()


def test_a_start_is_tried_again_on_a_link_error_only_as_often_as_asked() -> None:
    tries: list[int | None] = []

    def begin(seed: int | None) -> VehicleSnapshot:
        tries.append(seed)
        if len(tries) < 3:
            raise LinkError("no frame")
        return START

    assert start_with_retries(begin, 7) is START and tries == [7, 7, 7]
    tries.clear()
    with pytest.raises(LinkError):
        start_with_retries(begin, 8, attempts=2)
