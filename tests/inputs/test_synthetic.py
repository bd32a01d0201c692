"""Synthetic participants: profile validation, delay, noise, attention, patience (no SITL)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from companion.app import build_human
from companion.config import CompanionConfig, PilotConfig
from companion.errors import ConfigError
from companion.inputs.base import HelpRequest, HumanCommand, HumanInput
from companion.inputs.expert import InterveningExpert
from companion.inputs.synthetic import (
    PROFILES,
    OnCallPilot,
    PilotProfile,
    SyntheticPilot,
    on_call_pilot,
    profile_named,
    synthetic_pilot,
)
from companion.msg.command import JoystickCommand
from companion.msg.observation import Observation
from companion.msg.pad import PadDetection


def obs_at(step: int, down_m: float = -8.0, vd_m_s: float = 0.0) -> Observation:
    """An observation at control step ``step`` with the pad centred below."""
    pad = PadDetection(159.5, 119.5, 12.0, partial=False)
    return Observation((0.0, 0.0, down_m), (0.0, 0.0, 0.0), (0.0, 0.0, vd_m_s), (0.0, 0.0, 0.0),
                       pad, (320, 240), time_boot_ms=1000 + 95 * step)


class StepEcho(HumanInput):
    """A fake pilot that reports, in its roll stick, the step of the observation it was shown."""

    def __init__(self) -> None:
        self.seen_steps: list[int] = []
        self.resets = 0

    def read(self, obs: Observation) -> HumanCommand:
        step = (obs.time_boot_ms - 1000) // 95
        self.seen_steps.append(step)
        return HumanCommand(JoystickCommand((step % 100) / 100.0, 0.2, 0.0, -0.5), override_held=step % 2 == 0)

    def reset(self) -> None:
        self.resets += 1


def profile(**changes: object) -> PilotProfile:
    base = PilotProfile("T", 7, 0, (0.0, 0.0, 0.0, 0.0), 0.0, 1.0)
    return dataclasses.replace(base, **changes)  # type: ignore[arg-type]


@pytest.mark.parametrize("changes", [
    {"name": ""}, {"name": "P 1"}, {"seed": -1},
    {"reaction_delay_steps": -1}, {"reaction_delay_steps": 21}, {"reaction_delay_steps": 1.5},
    {"stick_noise_std": (0.1, 0.1, 0.1)}, {"stick_noise_std": (0.1, -0.1, 0.0, 0.0)},
    {"stick_noise_std": (0.1, float("nan"), 0.0, 0.0)},
    {"attention_lapse_prob": 1.0}, {"attention_lapse_prob": -0.1},
    {"patience": 0.1}, {"patience": 5.0},
])
def test_profile_rejects_bad_values(changes: dict[str, object]) -> None:
    with pytest.raises(ConfigError):
        profile(**changes)


def test_named_profiles_get_less_skilled_from_p1_to_p4() -> None:
    ps = [profile_named(n) for n in ("P1", "P2", "P3", "P4")]
    assert list(PROFILES) == ["P1", "P2", "P3", "P4"]
    assert [p.reaction_delay_steps for p in ps] == sorted(p.reaction_delay_steps for p in ps)
    assert [p.stick_noise_std[0] for p in ps] == sorted(p.stick_noise_std[0] for p in ps)
    assert len({p.seed for p in ps}) == 4 and all(p.description for p in ps)
    with pytest.raises(ConfigError, match="P1, P2, P3, P4"):
        profile_named("P9")


def test_delay_acts_on_the_observation_k_steps_old() -> None:
    inner = StepEcho()
    pilot = SyntheticPilot(profile(reaction_delay_steps=3), inner)
    pilot.reset()
    rolls = [pilot.read(obs_at(k)).command.roll for k in range(8)]
    assert inner.seen_steps == [0, 0, 0, 0, 1, 2, 3, 4]  # the first frame until 3 newer arrive
    assert rolls == pytest.approx([s / 100.0 for s in inner.seen_steps])
    pilot.reset()  # a new episode forgets the old screen
    pilot.read(obs_at(50))
    assert inner.seen_steps[-1] == 50 and inner.resets == 2


def test_no_delay_no_noise_no_lapses_is_the_inner_pilot() -> None:
    inner = StepEcho()
    pilot = SyntheticPilot(profile(), inner)
    for k in range(5):
        got = pilot.read(obs_at(k))
        assert got == HumanCommand(JoystickCommand(k / 100.0, 0.2, 0.0, -0.5), override_held=k % 2 == 0)


def test_stick_noise_has_the_profile_std_per_axis_and_stays_in_range() -> None:
    std = (0.05, 0.1, 0.0, 0.2)
    pilot = SyntheticPilot(profile(stick_noise_std=std), StepEcho())
    errors = []
    for _ in range(3000):
        got = pilot.read(obs_at(0)).command.to_array()  # inner: (0, 0.2, 0, -0.5)
        errors.append(got - np.array([0.0, 0.2, 0.0, -0.5]))
        assert np.all(np.abs(got) <= 1.0)
    measured = np.std(errors, axis=0)
    assert measured == pytest.approx(std, abs=0.01)
    assert measured[2] == 0.0  # no yaw noise asked for, none given


def test_attention_lapses_hold_the_last_command_at_the_profile_rate() -> None:
    inner = StepEcho()
    pilot = SyntheticPilot(profile(attention_lapse_prob=0.3, stick_noise_std=(0.05,) * 4), inner)
    answers = [pilot.read(obs_at(k)) for k in range(4000)]
    assert pilot.lapses == 4000 - len(inner.seen_steps)
    assert pilot.lapses / 4000 == pytest.approx(0.3, abs=0.03)
    held = [b for a, b in zip(answers, answers[1:]) if a == b]
    assert len(held) == pytest.approx(pilot.lapses, abs=2)  # a lapse repeats sticks and trigger exactly
    assert answers[0] is not None and inner.seen_steps[0] == 0  # the first step is always looked at


def test_episodes_are_seeded_by_profile_trial_and_episode() -> None:
    def run(trial_seed: int, episodes: int) -> list[list[float]]:
        pilot = SyntheticPilot(profile(stick_noise_std=(0.1,) * 4, attention_lapse_prob=0.2), StepEcho(), trial_seed)
        out = []
        for _ in range(episodes):
            pilot.reset()
            out.append([pilot.read(obs_at(k)).command.pitch for k in range(20)])
        return out

    a, b = run(0, 2), run(0, 2)
    assert a == b  # reproducible
    assert a[0] != a[1]  # episodes differ
    assert run(1, 1)[0] != a[0]  # trials differ
    assert run(0, 1)[0] == a[0]  # episode 0 does not depend on how many follow


def test_patience_scales_the_takeover_thresholds_and_keeps_the_config_valid() -> None:
    base = PilotConfig()
    patient = profile(patience=2.0).pilot_config(base)
    assert patient.takeover_descent_m_s == pytest.approx(2 * base.takeover_descent_m_s)
    assert patient.takeover_off_centre_m == pytest.approx(2 * base.takeover_off_centre_m)
    assert patient.takeover_stall_s == pytest.approx(2 * base.takeover_stall_s)
    assert patient.takeover_edge_fraction == pytest.approx(0.98)  # capped: the pad must stay on screen
    eager = profile(patience=0.25).pilot_config(base)
    assert eager.takeover_off_centre_m == pytest.approx(0.15)
    assert eager.release_off_centre_m <= eager.takeover_off_centre_m
    for cfg in (patient, eager):
        PilotConfig.model_validate(cfg.model_dump())  # the section's own checks still pass


def test_profiles_differ_in_strategy_not_only_in_noise() -> None:
    base = PilotConfig()
    configs = {name: p.pilot_config(base) for name, p in PROFILES.items()}
    assert len({c.anticipation_s for c in configs.values()}) == 4
    assert len({c.takeover_predicted_miss_m for c in configs.values()}) == 4
    assert configs["P3"].xy_gain_per_m > base.xy_gain_per_m > configs["P4"].xy_gain_per_m
    assert configs["P3"].descent_stick_fast < base.descent_stick_fast < configs["P4"].descent_stick_fast
    for cfg in configs.values():
        PilotConfig.model_validate(cfg.model_dump())


@pytest.mark.parametrize("changes", [{"anticipation_s": -1.0}, {"miss_margin_m": 0.0},
                                     {"correction_gain": 5.0}, {"descent_scale": 2.0}])
def test_profile_rejects_bad_strategies(changes: dict[str, object]) -> None:
    with pytest.raises(ConfigError):
        profile(**changes)


def test_a_patient_pilot_takes_over_later() -> None:
    """Descending at 2 m/s: beyond the default 1.5 m/s threshold, within 1.5 x 1.5 m/s."""
    def holds(patience: float) -> bool:
        pilot = synthetic_pilot(profile(patience=patience), PilotConfig())
        pilot.reset()
        return pilot.read(obs_at(0, vd_m_s=2.0)).override_held

    assert holds(1.0) is True
    assert holds(1.5) is False


def test_build_human_makes_a_seeded_synthetic_participant() -> None:
    cfg = CompanionConfig()
    cfg = cfg.model_copy(update={"session": cfg.session.model_copy(update={"seed": 3000})})
    human = build_human("synthetic:P3", cfg, None)  # type: ignore[arg-type]  # needs no link
    assert isinstance(human, SyntheticPilot) and isinstance(human.inner, InterveningExpert)
    assert human.profile is PROFILES["P3"] and human.trial_seed == 3000
    assert human.inner.rule.cfg.takeover_descent_m_s == pytest.approx(0.8 * 1.5)
    with pytest.raises(ConfigError):
        build_human("synthetic:nobody", cfg, None)  # type: ignore[arg-type]


def test_an_on_call_participant_answers_a_request_late_takes_over_and_lets_go() -> None:
    """Asked while all is well (the pad centred below, descending gently): they turn round,
    take over at once, and let go by their release rule once back on track and lower."""
    pilot = on_call_pilot(profile(), PilotConfig(), trial_seed=0, response_steps=3)
    assert pilot.robot_gated and isinstance(pilot, OnCallPilot)
    pilot.reset()
    assert pilot.read(obs_at(0)).command != JoystickCommand.neutral()  # a demonstration flies as usual
    pilot.on_request(HelpRequest(1, 0, 1, 0.5, 0.1))
    answers = [pilot.read(obs_at(1 + i, down_m=-8.0 + 0.1 * i, vd_m_s=0.5)) for i in range(60)]
    held = [a.override_held for a in answers]
    assert held[:3] == [False, False, False] and answers[0] == HumanCommand.neutral()
    assert held[3], "no take-over after the response delay"
    released = held.index(False, 3)
    assert 3 + 10 <= released < 60  # held through the release rule's time, then let go
    assert not any(held[released:]) and pilot.answered == 1
    pilot.on_request(None)  # the request closes: nothing changes while away


def test_build_human_makes_an_on_call_participant_when_asking() -> None:
    cfg = CompanionConfig()
    cfg = cfg.model_copy(update={"ask": cfg.ask.model_copy(update={"enabled": True, "synthetic_response_s": 1.0})})
    human = build_human("synthetic:P2", cfg, None)  # type: ignore[arg-type]
    assert isinstance(human, OnCallPilot) and human.response_steps == 10  # 1 s at 10.5 Hz, rounded
    assert human.pilot.profile is PROFILES["P2"]
