"""The one rule of how an episode ends and is scored (companion/control/outcome.py): its order and
cases, and that every driver of an episode flies by it. Replacing the rule in that one module
changes the session's records, the Gymnasium env's and the batched env's infos and rewards, and
the batched evaluation's records alike: no driver keeps a rule of its own."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from companion.config import CompanionConfig, LandingConfig, LearnerConfig, SafetyConfig
from companion.control import outcome
from companion.control.outcome import (
    FENCE,
    TIMEOUT,
    TOUCHDOWN,
    Score,
    Verdict,
    judge_frame,
    judge_snapshot,
    judge_vehicle,
    score,
    score_estimate,
    score_vehicle,
)
from companion.control.safety import FenceStatus, Geofence
from companion.control.touchdown import TouchdownAssist, TouchdownNeed
from companion.errors import ColError, SimulatorError
from companion.experiment.batched_eval import evaluate_batched
from companion.experiment.grid import TrainingRun, load_experiment
from companion.experiment.runner import evaluate_checkpoint, trial_config
from companion.learning.checkpoint import save_checkpoint
from companion.learning.dataset import HumanDataset
from companion.learning.learner import Learner
from companion.link.home import HomeFrame
from companion.msg.setpoint import VelocitySetpoint
from companion.msg.snapshot import VehicleSnapshot
from companion.rl.batched_env import BatchedLandingEnv
from companion.rl.gym_env import LandingEnv

PAPER = Path(__file__).resolve().parents[2] / "configs" / "paper.toml"
OUTSIDE = FenceStatus(False, "too far")
INSIDE = FenceStatus(True)
def snapshot_at(position_ned_m: tuple[float, float, float]) -> VehicleSnapshot:
    return VehicleSnapshot(0.0, 1000, 1000, 1, "PX4", True, "OFFBOARD", "IN_AIR", position_ned_m, (0.0, 0.0, 0.0),
                           (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0.0, True, True, home_ned_m=(0.0, 0.0, 0.0))


TRUTH = {"success": True, "distance_to_pad_m": 0.123456, "speed_m_s": 0.41234567}


# ----- the rule --------------------------------------------------------------------------------
def test_time_comes_first_then_a_touchdown_after_the_first_step_then_the_fence() -> None:
    assert judge_frame(10, 10, True, OUTSIDE) == TIMEOUT  # a frame after the last step is not looked at
    assert judge_frame(3, 10, True, OUTSIDE) == TOUCHDOWN
    assert judge_frame(0, 10, True, INSIDE) is None  # still standing from the reset
    assert judge_frame(0, 10, True, OUTSIDE) == FENCE
    assert judge_frame(3, 10, False, OUTSIDE) == FENCE
    assert judge_frame(3, 10, False, None) is None  # unusable telemetry: not judged, held
    assert judge_frame(3, 10, False, INSIDE) is None


def test_the_fence_is_judged_relative_to_home_and_not_on_unusable_telemetry() -> None:
    fence = Geofence.from_config(SafetyConfig(fence_radius_m=5.0))
    home = HomeFrame()
    far = snapshot_at(position_ned_m=(6.0, 0.0, -3.0))
    assert judge_snapshot(1, 10, far, fence, home) == FENCE
    assert judge_snapshot(1, 10, far, None, home) is None  # the autopilot lands by itself: no fence
    broken = dataclasses.replace(far, velocity_ned_m_s=(math.nan, 0.0, 0.0))
    assert judge_snapshot(1, 10, broken, fence, home) is None
    landed = dataclasses.replace(far, landed_state="ON_GROUND")
    assert judge_snapshot(1, 10, landed, fence, home) == TOUCHDOWN
    assert judge_snapshot(1, 10, far, fence, home, touched_down=True) == TOUCHDOWN  # the companion's evidence


def test_scores_by_truth() -> None:
    assert score(TOUCHDOWN, simulated=True, touchdown=TRUTH) == Score(True, 0.1235, 0.4123)
    assert score(TOUCHDOWN, simulated=True, touchdown={**TRUTH, "success": False}).reward == 0.0
    assert score(TOUCHDOWN, simulated=True, touchdown=TRUTH).reward == 1.0
    assert score(TOUCHDOWN, simulated=True, touchdown=None) == Score()  # no truth: unknown
    for other in (FENCE, TIMEOUT, "link_lost", "error", "stopped"):
        assert score(other, simulated=True, touchdown=TRUTH) == Score(success=False)


def test_scores_by_truth_where_known_else_by_estimate_with_and_without_a_judge() -> None:
    judged = score(TOUCHDOWN, simulated=False, estimated_distance_m=0.31, true_distance_m=0.52, judge_radius_m=0.5)
    assert judged == Score(False, 0.31, None, 0.52)  # on the pad by the estimate, off it by the truth
    assert score(TOUCHDOWN, simulated=False, estimated_distance_m=0.61, true_distance_m=0.2,
                 judge_radius_m=0.5) == Score(True, 0.61, None, 0.2)
    assert score(TOUCHDOWN, simulated=False, estimated_distance_m=0.31, judge_radius_m=0.5).success is True
    assert score(TOUCHDOWN, simulated=False, estimated_distance_m=0.7, judge_radius_m=0.5).success is False
    assert score(TOUCHDOWN, simulated=False, estimated_distance_m=0.31).success is None  # nobody judges
    assert score(TIMEOUT, simulated=False, judge_radius_m=0.5) == Score(success=False)
    assert score(TIMEOUT, simulated=False) == Score()


def standing_assist(snap: VehicleSnapshot, steps: int) -> TouchdownAssist:
    """An assist that has found the vehicle standing, asked down slowly, for ``steps`` steps."""
    assist = TouchdownAssist(TouchdownNeed(0.275, "PX4 test"), LandingConfig(evidence_touchdown_s=1.0), 0.1,
                             pad_height_m=1.5, home=HomeFrame())
    while assist.engaged_steps_total < steps:
        assist.apply(VelocitySetpoint(0.0, 0.0, 0.263, 0.0), snap)
    return assist


def test_a_vehicle_is_judged_by_its_landed_state_or_else_the_assists_evidence() -> None:
    fence, home = Geofence(30.0, -1.0, 25.0), HomeFrame()
    assert judge_vehicle(5, 5, None, fence, home) == Verdict(TIMEOUT)  # after the last step
    assert judge_vehicle(4, 5, None, fence, home) == Verdict(None)
    ground = dataclasses.replace(snapshot_at((0.0, 0.0, 0.0)), landed_state="ON_GROUND")
    assert judge_vehicle(3, 10, ground, fence, home) == Verdict(TOUCHDOWN)  # its own word: no note
    silent = dataclasses.replace(ground, landed_state="UNDEFINED")
    assert judge_vehicle(3, 10, silent, fence, home, standing_assist(silent, 9)) == Verdict(None)  # not yet
    verdict = judge_vehicle(3, 10, silent, fence, home, standing_assist(silent, 10))  # 1 s of it
    assert verdict.outcome == TOUCHDOWN and verdict.evidence is not None
    assert verdict.evidence.note == "touchdown judged by the companion: no landed state, standing"
    assert not verdict.evidence.stand_down  # standing on a real surface: its own detector lands it


def test_a_vehicle_outside_the_fence_says_why_unless_it_stands() -> None:
    fence, home = Geofence(5.0, -1.0, 25.0), HomeFrame()
    assert judge_vehicle(1, 10, snapshot_at((6.0, 0.0, -3.0)), fence, home) == \
        Verdict(FENCE, fence_reason="6.0 m from the centre, fence radius 5 m")
    sunk = snapshot_at((0.0, 0.0, 1.4))  # 1.4 m below home: a drifting estimate, or flying below
    assert judge_vehicle(1, 10, sunk, fence, home).fence_reason == "altitude -1.4 m below the fence's -1 m"
    assert judge_vehicle(1, 10, sunk, fence, home, standing_assist(sunk, 1)) == Verdict(None)
    assert judge_vehicle(1, 10, snapshot_at((6.0, 0.0, -3.0)), None, home) == Verdict(None)  # no fence kept


PAD = (1.0, 2.0, -1.5)


def test_an_estimated_touchdown_is_scored_from_home_and_says_how() -> None:
    result, notes = score_estimate(TOUCHDOWN, (4.0, 6.0, -0.1), PAD, home_known=True, true_distance_m=5.123456,
                                   judge_radius_m=5.5)
    assert result == Score(True, 5.0, None, 5.1235)  # 3-4-5 from the pad; the truth beside it, and judging
    assert notes == ["touchdown distance estimated from the vehicle's position relative to home",
                     "success judged by the autopilot's ground truth (the pad where the truth puts it)"]
    result, notes = score_estimate(TOUCHDOWN, (4.0, 6.0, -0.1), PAD, home_known=True, judge_radius_m=5.5)
    assert result == Score(True, 5.0, None, None)
    assert notes[-1] == "success judged from the vehicle's reported position (the rendered pad is where it puts it)"
    result, notes = score_estimate(TOUCHDOWN, (4.0, 6.0, -0.1), PAD, home_known=False)
    assert result == Score(None, 5.0, None, None)  # nobody judges
    assert notes == ["touchdown distance estimated from the vehicle's position (no HOME_POSITION: from z = 0)"]


def test_no_estimate_without_a_touchdown_or_telemetry() -> None:
    assert score_estimate(TIMEOUT, (1.0, 2.0, -3.0), PAD, home_known=True, true_distance_m=0.1,
                          judge_radius_m=0.5) == (Score(success=False), [])
    assert score_estimate(TOUCHDOWN, None, PAD, home_known=True, judge_radius_m=0.5) == (Score(), [])
    assert score_estimate(FENCE, None, PAD, home_known=True) == (Score(), [])


def test_a_vehicle_is_scored_by_its_simulator_where_it_has_one_else_by_its_estimate() -> None:
    home = HomeFrame()
    touchdown = {"touchdown": {"success": True, "distance_to_pad_m": 0.123456, "speed_m_s": 0.4}}
    assert score_vehicle(TOUCHDOWN, snapshot_at((4.0, 6.0, -0.1)), home, PAD, judge_radius_m=0.5,
                         simulator_truth=lambda: touchdown) == (Score(True, 0.1235, 0.4), [])

    def refused() -> dict[str, Any]:
        raise SimulatorError("control surface timed out")

    result, notes = score_vehicle(TOUCHDOWN, None, home, PAD, simulator_truth=refused)
    assert result == Score() and notes == ["no ground truth: control surface timed out"]  # unknown, and said
    assert issubclass(SimulatorError, ColError)
    result, notes = score_vehicle(TOUCHDOWN, snapshot_at((4.0, 6.0, -0.1)), home, PAD, judge_radius_m=5.5)
    assert result == Score(True, 5.0, None, None)  # no simulator: the estimate, as score_estimate
    assert notes[0].startswith("touchdown distance estimated from the vehicle's position")
    assert score_vehicle(TIMEOUT, None, home, PAD, judge_radius_m=5.5) == (Score(success=False), [])


# ----- every driver flies by it ----------------------------------------------------------------
ENDS_AT = 2
MARK = Score(True, 42.0, 4.2)


@pytest.fixture
def replaced_rule(monkeypatch: pytest.MonkeyPatch) -> None:
    """Another rule: every episode ends after two steps, and every ending is a success 42 m off."""
    monkeypatch.setattr(outcome, "judge_frame",
                        lambda steps_taken, max_steps, touched_down, fence: TIMEOUT if steps_taken >= ENDS_AT else None)
    monkeypatch.setattr(outcome, "score", lambda result, **_: MARK)


def _steps_until_done(step: Any, action: np.ndarray) -> tuple[int, tuple[Any, ...]]:
    """Steps an env (Gymnasium's or a vec env of one) until its episode ends: (steps, last result)."""
    for n in range(1, 50):
        result = step(action)
        done = result[2] or result[3] if len(result) == 5 else result[2][0]
        if done:
            return n, result
    raise AssertionError("the episode did not end")


@pytest.mark.e2e
def test_replacing_the_rule_changes_every_driver(replaced_rule: None, tmp_path: Path) -> None:
    cfg = CompanionConfig()
    env = LandingEnv(2, cfg, inprocess=True)
    try:
        env.reset(seed=3)
        steps, (_, reward, _, _, info) = _steps_until_done(env.step, np.zeros(2, np.float32))
    finally:
        env.close()
    assert (steps, reward, info["steps"], info["success"], info["touchdown_distance_m"]) == (ENDS_AT, 1.0, ENDS_AT, True, 42.0)

    batched = BatchedLandingEnv(1, 2, cfg)
    try:
        batched.seed(3)
        batched.reset()
        steps, (_, rewards, _, infos) = _steps_until_done(batched.step, np.zeros((1, 2), np.float32))
    finally:
        batched.close()
    assert (steps, rewards[0], infos[0]["success"], infos[0]["touchdown_distance_m"]) == (ENDS_AT, 1.0, True, 42.0)

    path = tmp_path / "experiment.toml"
    path.write_text(PAPER.read_text())
    setup = load_experiment(path)
    setup = dataclasses.replace(setup, exp=setup.exp.model_copy(update={"eval_runs": 1, "eval_batched": False}))
    trial = trial_config(setup, TrainingRun("P1", "demo", 0, 2, (2,)))
    policy = Learner(trial.learner, HumanDataset(None)).latest_snapshot
    checkpoint = save_checkpoint(tmp_path / "policy.npz", policy, LearnerConfig(), dataset_size=0, episode=1,
                                 condition="demo")
    (tmp_path / "session").mkdir()
    evaluate_checkpoint(setup, trial, checkpoint, tmp_path / "session")
    session = json.loads((tmp_path / "session" / "eval_episodes.jsonl").read_text().splitlines()[0])
    lanes = evaluate_batched(trial, checkpoint, setup.exp.eval_seed, 1, path).records[0].to_json_dict()
    for record in (session, lanes):
        assert (record["steps"], record["success"], record["touchdown_distance_m"], record["touchdown_speed_m_s"]) \
            == (ENDS_AT, True, 42.0, 4.2)
