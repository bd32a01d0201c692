"""One control step's decision (companion/control/step.py): who flies, the setpoint as the
vehicle is sent it (mapped, limited, then the touchdown assist) and the sample it records."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from companion.commands import CommandMapper
from companion.config import CompanionConfig, LandingConfig
from companion.control.arbiter import Phase
from companion.control.link_port import HOLD
from companion.control.safety import SetpointLimiter
from companion.control.step import PolicyRunner, StepPipeline
from companion.control.touchdown import TouchdownAssist, TouchdownNeed, VehicleTouchdown
from companion.inputs.base import HumanCommand, HumanInput
from companion.learning.policy import PolicyNet
from companion.learning.snapshot import PolicySnapshot
from companion.link.home import HomeFrame
from companion.msg.command import JoystickCommand
from companion.msg.observation import Observation
from companion.msg.sample import Source
from companion.msg.snapshot import VehicleSnapshot

CFG = CompanionConfig()
PERIOD_S = 0.1
DOWN = JoystickCommand(0.0, 0.5, 0.0, -1.0)  # forward half, down at full stick


class Sticks(HumanInput):
    def __init__(self, override: bool = False) -> None:
        self.override, self.resets = override, 0

    def read(self, obs: Observation) -> HumanCommand:
        return HumanCommand(DOWN, self.override)

    def reset(self) -> None:
        self.resets += 1


class Runner:
    def __init__(self, snapshot: PolicySnapshot, error: BaseException | None = None) -> None:
        self.latest_snapshot, self.error = snapshot, error

    def on_control_step(self, tick_start_s: float | None = None) -> PolicySnapshot:
        return self.latest_snapshot


@dataclass
class Parts:
    mapper: CommandMapper
    human: HumanInput
    limiter: SetpointLimiter
    runner: PolicyRunner | None = None


def pipeline(human: HumanInput | None = None, runner: PolicyRunner | None = None,
             assist: TouchdownAssist | None = None, limiter: SetpointLimiter | None = None) -> tuple[StepPipeline, Parts]:
    parts = Parts(CommandMapper(CFG.commands), human or Sticks(), limiter or SetpointLimiter(CFG.commands, CFG.safety),
                  runner)
    touchdown = VehicleTouchdown(None, PERIOD_S, 1.5, HomeFrame(), 1.0, None)  # type: ignore[arg-type]
    touchdown.assist = assist
    return StepPipeline(parts, PERIOD_S, None, touchdown), parts


def snap(down_m: float = -3.0) -> VehicleSnapshot:
    return VehicleSnapshot(0.0, 1500, 1500, 1, "PX4", True, "OFFBOARD", "IN_AIR", (0.0, 0.0, down_m), (0.0, 0.0, 0.0),
                           (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0.0, True, True)


def observe(s: VehicleSnapshot, frame_missing: bool = False) -> tuple[Observation, np.ndarray]:
    obs = Observation(s.position_ned_m, s.attitude_rad, s.velocity_ned_m_s, s.rates_frd_rad_s, None, (320, 240),
                      s.time_boot_ms, frame_missing)
    return obs, obs.to_vector()


def test_a_demonstration_step_flies_the_persons_command_mapped_and_limited_and_records_it() -> None:
    step, parts = pipeline()
    obs, vector = observe(snap())
    choice = step.decide(Phase.DEMONSTRATION, 4, obs, vector, snap())
    assert choice.decision.source == "human" and choice.decision.command == DOWN
    assert choice.setpoint == SetpointLimiter(CFG.commands, CFG.safety).apply(parts.mapper.to_setpoint(DOWN), PERIOD_S)
    assert choice.shown == choice.setpoint and (choice.version, np.isnan(choice.score)) == (None, True)
    sample = choice.sample(2, 4, 1000, obs, vector)
    assert sample is not None and (sample.episode, sample.step, sample.time_s, sample.source) == \
        (2, 4, 0.5, Source.DEMONSTRATION)
    np.testing.assert_array_equal(sample.action, DOWN.to_array())
    assert step.arbiter.summary().recorded_steps == 1


def test_without_a_camera_frame_the_step_flies_but_records_nothing() -> None:
    step, _ = pipeline()
    obs, vector = observe(snap(), frame_missing=True)
    choice = step.decide(Phase.DEMONSTRATION, 0, obs, vector, snap())
    assert choice.setpoint is not None and choice.sample(0, 0, 0, obs, vector) is None


def test_the_policy_flies_an_autonomous_step_and_a_failed_learner_is_said_once(caplog: pytest.LogCaptureFixture) -> None:
    policy = PolicyNet(15, (8,), init_std=0.1).snapshot()
    step, parts = pipeline(runner=Runner(policy, error=RuntimeError("boom")))
    obs, vector = observe(snap())
    choices = [step.decide(Phase.AUTONOMOUS, i, obs, vector, snap()) for i in range(3)]
    assert all(c.decision.source == "policy" and c.version == policy.version for c in choices)
    assert choices[0].decision.command == parts.mapper.command_from_values(policy.act(vector))
    assert caplog.text.count("learner failed (boom)") == 1
    assert choices[0].sample(0, 0, 0, obs, vector) is None  # the policy's commands are never recorded


def test_the_touchdown_assist_comes_after_the_limiter() -> None:
    assist = TouchdownAssist(TouchdownNeed(0.275, "PX4 test"), LandingConfig(), PERIOD_S, 1.5, HomeFrame(), 1.0)
    slow = Sticks()
    step, parts = pipeline(slow, assist=assist)
    ground = snap(down_m=0.0)
    obs, vector = observe(ground)
    slow_down = JoystickCommand(0.0, 0.0, 0.0, -0.3)
    limited = [step.limited(slow_down) for _ in range(assist.window_steps + 1)]
    sent = [step.setpoint(slow_down, ground) for _ in range(assist.window_steps + 1)]
    assert limited[-1].down_m_s < sent[-1].down_m_s == pytest.approx(assist.wanted_m_s)
    assert sent[-1].down_m_s <= parts.limiter.max_down_m_s


def test_a_new_episode_resets_the_count_the_person_and_the_limiter() -> None:
    human = Sticks()
    rate_limited = SetpointLimiter(CFG.commands, CFG.safety.model_copy(update={"max_accel_xy_m_s2": 1.0}))
    step, _ = pipeline(human, limiter=rate_limited)
    obs, vector = observe(snap())
    flown = step.decide(Phase.DEMONSTRATION, 0, obs, vector, snap()).setpoint
    assert flown is not None and flown.forward_m_s > 0.5
    assert step.limited(JoystickCommand.neutral()).forward_m_s == pytest.approx(flown.forward_m_s - 0.1)  # 1 m/s2
    step.reset()
    assert (step.arbiter.summary().steps, human.resets) == (0, 1)
    assert step.limited(JoystickCommand.neutral()) == HOLD  # what is asked now, not a slowing from before
