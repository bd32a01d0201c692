"""The human operator model, property by property (no SITL): reaction times as set, take-over
after detection delay plus reaction time (or missed and looked at again), a reaction time to let
go, the neuromuscular lag, remnant proportional to the command, perception from the video and
the HUD, the perception delay, lapses, fatigue, and participants drawn from a population."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from companion.app import build_human
from companion.config import CompanionConfig, PilotConfig
from companion.errors import ConfigError
from companion.experiment.grid import ExperimentConfig
from companion.inputs.base import HumanCommand, HumanInput
from companion.inputs.operator import (
    POPULATION_SEED,
    HumanOperatorPilot,
    OperatorPopulation,
    OperatorTraits,
    TakeOver,
    operator_named,
    perceived,
)
from companion.msg.command import JoystickCommand
from companion.msg.observation import Observation
from companion.msg.pad import PadDetection

RATE_HZ = 10.5
PERIOD_S = 1 / RATE_HZ


def obs_at(step: int, u: float = 159.5, radius: float = 12.0) -> Observation:
    return Observation((1.234, -0.456, -7.891), (0.0123, -0.0234, 1.0), (0.333, -0.277, 0.456), (0.1, 0.2, 0.3),
                       PadDetection(u, 119.5, radius, partial=False), (320, 240), time_boot_ms=1000 + 95 * step)


def traits(**changes: object) -> OperatorTraits:
    """A person with every imperfection off, changed where a test asks."""
    base = dataclasses.replace(
        OperatorPopulation().participant(1), perception_delay_s=0.0, reaction_time_median_s=0.5,
        reaction_time_shape=0.0, neuromuscular_lag_s=0.0, remnant_ratio=0.0, remnant_floor=0.0, detection_prob=1.0,
        detection_delay_s=0.0, recheck_s=1.0, lapse_prob=0.0, fatigue_per_episode=0.0, pad_centre_error_px=0.0,
        pad_size_weber=0.0)
    return dataclasses.replace(base, **changes)  # type: ignore[arg-type]


class Scripted(HumanInput):
    """Sticks and judgement from a script: ``commands[i]`` and ``flags[i]`` at the i-th read; it
    also records the observations it was shown."""

    def __init__(self, commands: list[JoystickCommand] | None = None, flags: list[bool] | None = None) -> None:
        self.commands, self.flags = commands or [], flags or []
        self.seen: list[Observation] = []

    def read(self, obs: Observation) -> HumanCommand:
        i = len(self.seen)
        self.seen.append(obs)
        cmd = self.commands[min(i, len(self.commands) - 1)] if self.commands else JoystickCommand.neutral()
        flag = self.flags[min(i, len(self.flags) - 1)] if self.flags else False
        return HumanCommand(cmd, override_held=flag)

    def reset(self) -> None:
        self.seen = []


def pilot(t: OperatorTraits, inner: HumanInput, seed: int = 0) -> HumanOperatorPilot:
    p = HumanOperatorPilot(t, PilotConfig(), RATE_HZ, seed, inner=inner)
    p.reset()
    return p


def test_reaction_times_are_log_normal_with_the_participants_median_and_shape() -> None:
    t = traits(reaction_time_median_s=0.42, reaction_time_shape=0.25)
    rng = np.random.default_rng(3)
    rts = np.array([t.draw_reaction_s(rng) for _ in range(20_000)])
    assert np.median(rts) == pytest.approx(0.42, rel=0.02)
    assert np.std(np.log(rts)) == pytest.approx(0.25, rel=0.03)
    assert np.mean(rts) > np.median(rts)  # right-skewed, as reaction times are


def test_a_flag_is_taken_over_after_the_detection_delay_plus_a_reaction_time() -> None:
    t = traits(detection_delay_s=0.3, reaction_time_median_s=0.5, reaction_time_shape=0.0)
    take = TakeOver(t, PERIOD_S, np.random.default_rng(0))
    held = [take.update(i >= 5) for i in range(30)]
    first = held.index(True)
    assert first == 5 + round(0.8 / PERIOD_S)  # 8 steps after the flag at step 5
    assert take.latencies_s == [pytest.approx(8 * PERIOD_S)]
    released = [take.update(False) for _ in range(10)]  # the rule says let go: a reaction time later
    assert released[:round(0.5 / PERIOD_S)] == [True] * round(0.5 / PERIOD_S) and released[-1] is False


def test_a_flag_that_clears_before_the_person_reacts_is_never_taken_over() -> None:
    take = TakeOver(traits(detection_delay_s=1.0), PERIOD_S, np.random.default_rng(0))
    assert not any(take.update(4 <= i < 8) for i in range(40))
    assert take.events == 1 and take.latencies_s == []


def test_missed_trouble_is_looked_at_again_after_the_recheck_time() -> None:
    take = TakeOver(traits(detection_prob=0.0, recheck_s=2.0), PERIOD_S, np.random.default_rng(0))
    assert not any(take.update(True) for _ in range(100))  # never noticed
    looks = 100 // (round(2.0 / PERIOD_S) + 1)
    assert take.missed == take.events and abs(take.events - looks) <= 1


def test_detection_happens_with_the_participants_probability() -> None:
    caught = 0
    for seed in range(2000):
        take = TakeOver(traits(detection_prob=0.85), PERIOD_S, np.random.default_rng(seed))
        take.update(True)
        caught += take.missed == 0
    assert caught / 2000 == pytest.approx(0.85, abs=0.025)


def test_the_stick_follows_through_a_first_order_neuromuscular_lag() -> None:
    p = pilot(traits(neuromuscular_lag_s=0.12), Scripted([JoystickCommand(0.0, 1.0, 0.0, 0.0)]))
    pitch = [p.read(obs_at(i)).command.pitch for i in range(8)]
    expected = [1 - math.exp(-(i + 1) * PERIOD_S / 0.12) for i in range(8)]
    assert pitch == pytest.approx(expected, abs=1e-9)


@pytest.mark.parametrize("stick", [0.0, 0.3, 0.8])
def test_remnant_noise_grows_with_the_command(stick: float) -> None:
    p = pilot(traits(remnant_ratio=0.1, remnant_floor=0.01), Scripted([JoystickCommand(stick, 0.0, 0.0, 0.0)]))
    roll = np.array([p.read(obs_at(i)).command.roll for i in range(4000)])
    assert np.std(roll) == pytest.approx(0.1 * stick + 0.01, rel=0.06)
    assert np.mean(roll) == pytest.approx(stick, abs=0.01)


def test_the_person_sees_the_video_with_error_and_the_hud_as_shown() -> None:
    t = traits(pad_centre_error_px=2.0, pad_size_weber=0.08)
    rng = np.random.default_rng(1)
    seen = [perceived(obs_at(0), t, rng) for _ in range(4000)]
    us = np.array([s.pad.u_px for s in seen if s.pad is not None])
    radii = np.array([s.pad.radius_px for s in seen if s.pad is not None])
    assert np.std(us) == pytest.approx(2.0, rel=0.05) and np.mean(us) == pytest.approx(159.5, abs=0.1)
    assert np.std(radii / 12.0) == pytest.approx(0.08, rel=0.05)
    one = seen[0]
    assert one.position_ned_m == pytest.approx((1.2, -0.5, -7.9)) and one.velocity_ned_m_s == pytest.approx((0.3, -0.3, 0.5))
    assert one.attitude_rad == pytest.approx(tuple(round(math.degrees(a)) * math.pi / 180 for a in (0.0123, -0.0234, 1.0)))
    assert one.rates_frd_rad_s == (0.0, 0.0, 0.0)
    assert perceived(dataclasses.replace(obs_at(0), pad=None), t, rng).pad is None


def test_the_person_acts_on_what_they_saw_the_perception_delay_ago() -> None:
    inner = Scripted()
    p = pilot(traits(perception_delay_s=0.28), inner)  # 3 steps at 10.5 Hz
    for i in range(10):
        p.read(obs_at(i))
    shown = [(o.time_boot_ms - 1000) // 95 for o in inner.seen]
    assert shown == [0, 0, 0, 0, 1, 2, 3, 4, 5, 6]


def test_attention_lapses_hold_the_last_command_at_the_participants_rate() -> None:
    commands = [JoystickCommand(0.0, 0.0, 0.0, (i % 20) / 20) for i in range(5000)]
    p = pilot(traits(lapse_prob=0.05), Scripted(commands))
    for i in range(5000):
        p.read(obs_at(i))
    assert p.lapses / 5000 == pytest.approx(0.05, abs=0.01)


def test_fatigue_lowers_detection_and_slows_reactions_over_the_session() -> None:
    t = traits(detection_prob=0.9, reaction_time_median_s=0.4, detection_delay_s=0.5, lapse_prob=0.02,
               fatigue_per_episode=0.01)
    tired = t.at_episode(20)
    assert tired.detection_prob == pytest.approx(0.9 * 0.8) and tired.reaction_time_median_s == pytest.approx(0.48)
    assert tired.detection_delay_s == pytest.approx(0.6) and tired.lapse_prob == pytest.approx(0.04)
    assert t.at_episode(0) == t
    p = pilot(dataclasses.replace(t, detection_prob=1.0), Scripted())
    for _ in range(10):
        p.reset()
    assert p.traits.detection_prob == pytest.approx(1.0 * (1 - 0.01 * 10))


def test_participants_are_drawn_from_the_population_reproducibly_and_within_their_ranges() -> None:
    population = OperatorPopulation()
    people = [population.participant(i) for i in range(1, 13)]
    assert people == [OperatorPopulation(POPULATION_SEED).participant(i) for i in range(1, 13)]
    assert len({p.reaction_time_median_s for p in people}) == 12
    for p in people:
        assert 0.35 <= p.reaction_time_median_s <= 0.55 and 0.18 <= p.perception_delay_s <= 0.35
        assert 0.8 <= p.detection_prob <= 0.97 and 0.08 <= p.neuromuscular_lag_s <= 0.15
        assert 0.8 <= p.strategy.patience <= 1.5 and 1.0 <= p.strategy.anticipation_s <= 4.0
    assert operator_named("H03") == people[2]
    assert operator_named("H03p7") == OperatorPopulation(7).participant(3) != people[2]
    assert operator_named("P1") is None and operator_named("H3") is None
    with pytest.raises(ConfigError, match="numbered from 1"):
        population.participant(0)
    with pytest.raises(ConfigError, match="detection_prob"):
        traits(detection_prob=1.5)


def test_a_grid_and_the_app_take_the_models_participants() -> None:
    assert ExperimentConfig(participants=("H01", "H12", "P2")).participants == ("H01", "H12", "P2")
    with pytest.raises(ValueError, match="H01, H02"):
        ExperimentConfig(participants=("Bob",))
    human = build_human("synthetic:H05", CompanionConfig(), None)
    assert isinstance(human, HumanOperatorPilot) and human.base == operator_named("H05")
    human.reset()
    command = human.read(obs_at(0))
    assert isinstance(command, HumanCommand) and all(math.isfinite(x) for x in command.command.to_array())
