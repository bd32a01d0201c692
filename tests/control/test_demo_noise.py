"""Noise on what the vehicle flies while the person demonstrates (companion/control/demo_noise.py,
DART): seeded per episode, within the sticks' range, on demonstration steps only, and the sample
always keeps the person's own command."""

from __future__ import annotations

import numpy as np
import pytest

from companion.control.arbiter import Phase
from companion.control.demo_noise import DemoNoise
from companion.control.safety import SetpointLimiter
from companion.msg.command import JoystickCommand
from companion.msg.sample import Source
from tests.control.test_step import CFG, DOWN, PERIOD_S, Sticks, observe, pipeline, snap


def commands(noise: DemoNoise, episode: int, n: int = 5) -> list[JoystickCommand]:
    noise.begin(episode)
    return [noise.flown(JoystickCommand.neutral()) for _ in range(n)]


def test_the_noise_is_the_same_for_the_same_seed_and_episode_and_differs_between_episodes() -> None:
    a, b = DemoNoise(0.2, seed=3), DemoNoise(0.2, seed=3)
    assert commands(a, 1) == commands(b, 1)
    assert commands(a, 1) != commands(a, 2)
    assert commands(a, 1) != commands(DemoNoise(0.2, seed=4), 1)
    spread = np.array([c.to_array() for c in commands(a, 7, n=2000)])
    assert spread.std(axis=0) == pytest.approx([0.2] * 4, rel=0.1)


def test_noisy_sticks_stay_within_their_range() -> None:
    noise = DemoNoise(1.0, seed=0)
    noise.begin(0)
    full = JoystickCommand(1.0, -1.0, 1.0, -1.0)
    flown = np.array([noise.flown(full).to_array() for _ in range(500)])
    assert flown.min() >= -1.0 and flown.max() <= 1.0 and np.ptp(flown, axis=0).min() > 0.5


@pytest.mark.parametrize("std", [-0.1, float("nan")])
def test_a_bad_std_is_refused(std: float) -> None:
    with pytest.raises(ValueError, match="noise std"):
        DemoNoise(std, seed=0)


def test_a_demonstration_step_flies_the_noisy_sticks_and_records_the_persons_own() -> None:
    step, parts = pipeline()
    step.noise = DemoNoise(0.3, seed=1)
    step.reset(episode=5)
    obs, vector = observe(snap())
    choice = step.decide(Phase.DEMONSTRATION, 0, obs, vector, snap())
    clean = SetpointLimiter(CFG.commands, CFG.safety).apply(parts.mapper.to_setpoint(DOWN), PERIOD_S)
    assert choice.setpoint is not None and choice.setpoint != clean
    sample = choice.sample(5, 0, 0, obs, vector)
    assert sample is not None and sample.source is Source.DEMONSTRATION
    np.testing.assert_array_equal(sample.action, DOWN.to_array())


def test_an_intervention_is_never_perturbed() -> None:
    step, parts = pipeline(Sticks(override=True))
    step.noise = DemoNoise(0.3, seed=1)
    step.reset(episode=5)
    obs, vector = observe(snap())
    choice = step.decide(Phase.INTERVENTION, 0, obs, vector, snap())
    assert choice.decision.tag == "intervention"
    assert choice.setpoint == SetpointLimiter(CFG.commands, CFG.safety).apply(parts.mapper.to_setpoint(DOWN), PERIOD_S)
