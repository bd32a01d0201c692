"""A human operator model: participants closer to people than the four scripted profiles.

The scripted participants (:mod:`companion.inputs.synthetic`) judge from exact telemetry with
a fixed delay, take over the moment their rule says so and never tire. People see a video and a
HUD, react late by a varying amount, move the sticks through muscles, add noise that grows with
what they do, miss some of what goes wrong, and tire. Each property comes from the
manual-control and human-performance literature, with the figures taken from it:

- **Perception** (what a person has at the console): the pad as seen in the video (its centre
  with a few pixels of error, its size within a Weber fraction: size discrimination runs at
  3-12 %, e.g. Teghtsoonian 1971) and the HUD's numbers as shown (heights and speeds to 0.1,
  angles to 1 degree), never exact state.
- **Effective time delay** of continuous control: McRuer & Jex (1967, "A review of quasi-linear
  pilot models", IEEE Trans. HFE-8) give 0.2-0.4 s for a person closing a loop on an integrator-
  like element; drawn per person in [0.18, 0.35] s, acted on in whole control steps.
- **Reaction time** to a discrete event (taking over, letting go), drawn *per event*: choice
  reaction times are right-skewed with medians of 0.35-0.55 s (Welford 1980; Luce 1986,
  "Response Times"); log-normal with a per-person median in that range and shape 0.25.
- **Neuromuscular lag** on the sticks: a first-order lag of 0.08-0.15 s (McRuer & Jex 1967,
  T_N about 0.1 s).
- **Remnant**: noise proportional to the command (Levison, Baron & Kleinman 1969, "A model for
  human controller remnant": observation and motor noise about -20 dB, i.e. a noise standard
  deviation about 0.1 of the signal's), ratio 0.05-0.15 plus a small floor.
- **Take-over decisions**: trouble the person's judgement (the intervention rule on what they
  perceive) flags is noticed with a probability per event (0.80-0.97) after a detection delay
  (0.2-1.0 s) plus a reaction time; a miss is looked at again 1-3 s later. Letting go also
  waits a reaction time.
- **Attention and fatigue**: lapses (the last command held) with a per-step probability, and a
  vigilance decrement over the session (Mackworth 1948; Warm, Parasuraman & Matthews 2008,
  "Vigilance requires hard mental work and is stressful": detection falls 10-20 % within
  15-30 min): per episode, detection probability falls and reaction times and lapses grow by
  ``fatigue_per_episode`` (0.2-1 % an episode).

Participants are drawn from a population (:class:`OperatorPopulation`): participant ``Hnn`` of
population seed ``s`` is a pure function of (s, nn), so a grid can have 8 or 12 of them. Their
strategy (anticipation, margin, correction gain, approach, patience) is drawn from the ranges of
the four scripted profiles. The dataset records the companion's observation with the person's
command, as for every pilot: the perceived observation only decides what the person does.
"""

from __future__ import annotations

import math
import re
from collections import deque
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from companion.config import PilotConfig
from companion.errors import ConfigError
from companion.inputs.base import HumanCommand, HumanInput
from companion.inputs.expert import InterveningExpert
from companion.inputs.synthetic import PilotProfile
from companion.msg.command import JoystickCommand

if TYPE_CHECKING:
    from companion.msg.observation import Observation

POPULATION_SEED = 2026
"""The default population: participants H01, H02, ... are drawn from it."""
HUD_METRES, HUD_SPEED, HUD_DEGREES = 0.1, 0.1, 1.0
_NAME = re.compile(r"H(\d{2})(?:p(\d+))?")


@dataclass(frozen=True)
class OperatorTraits:
    """One person's parameters (the module docstring says where each range comes from)."""

    name: str
    seed: int
    perception_delay_s: float
    reaction_time_median_s: float
    reaction_time_shape: float
    neuromuscular_lag_s: float
    remnant_ratio: float
    remnant_floor: float
    detection_prob: float
    detection_delay_s: float
    recheck_s: float
    lapse_prob: float
    fatigue_per_episode: float
    pad_centre_error_px: float
    pad_size_weber: float
    strategy: PilotProfile

    def __post_init__(self) -> None:
        checks = {"perception_delay_s": (0.0, 2.0), "reaction_time_median_s": (0.05, 3.0),
                  "reaction_time_shape": (0.0, 1.5), "neuromuscular_lag_s": (0.0, 1.0),
                  "remnant_ratio": (0.0, 1.0), "remnant_floor": (0.0, 0.5), "detection_prob": (0.0, 1.0),
                  "detection_delay_s": (0.0, 5.0), "recheck_s": (0.1, 10.0), "lapse_prob": (0.0, 0.5),
                  "fatigue_per_episode": (0.0, 0.05), "pad_centre_error_px": (0.0, 50.0),
                  "pad_size_weber": (0.0, 0.5)}
        for field_name, (lo, hi) in checks.items():
            value = getattr(self, field_name)
            if not (isinstance(value, int | float) and math.isfinite(value) and lo <= value <= hi):
                raise ConfigError(f"operator {self.name}: {field_name} must be in [{lo}, {hi}], got {value!r}")

    def at_episode(self, episode: int) -> OperatorTraits:
        """The person ``episode`` episodes into the session: the vigilance decrement applied."""
        tired = self.fatigue_per_episode * max(0, episode)
        return replace(self, detection_prob=self.detection_prob * max(0.0, 1.0 - tired),
                       reaction_time_median_s=self.reaction_time_median_s * (1.0 + tired),
                       detection_delay_s=self.detection_delay_s * (1.0 + tired),
                       lapse_prob=min(0.5, self.lapse_prob * (1.0 + 5.0 * tired)))

    def draw_reaction_s(self, rng: np.random.Generator) -> float:
        """One reaction time (log-normal around the median)."""
        return float(self.reaction_time_median_s * math.exp(self.reaction_time_shape * rng.standard_normal()))


class OperatorPopulation:
    """Participants drawn from ranges; ``participant(i)`` is a pure function of (seed, i)."""

    def __init__(self, seed: int = POPULATION_SEED) -> None:
        self.seed = seed

    def participant(self, index: int) -> OperatorTraits:
        if index < 1:
            raise ConfigError(f"participants are numbered from 1, got {index}")
        rng = np.random.default_rng([self.seed, index])
        u = rng.uniform
        name = f"H{index:02d}" + ("" if self.seed == POPULATION_SEED else f"p{self.seed}")
        strategy = PilotProfile(name, int(rng.integers(0, 2**31)), 0, (0.0, 0.0, 0.0, 0.0), 0.0,
                                round(float(u(0.8, 1.5)), 3), "drawn from the operator population",
                                anticipation_s=round(float(u(1.0, 4.0)), 3), miss_margin_m=round(float(u(0.3, 0.7)), 3),
                                correction_gain=round(float(u(0.7, 1.3)), 3), descent_scale=round(float(u(0.8, 1.2)), 3))
        return OperatorTraits(
            name=name, seed=strategy.seed,
            perception_delay_s=float(u(0.18, 0.35)), reaction_time_median_s=float(u(0.35, 0.55)),
            reaction_time_shape=0.25, neuromuscular_lag_s=float(u(0.08, 0.15)),
            remnant_ratio=float(u(0.05, 0.15)), remnant_floor=float(u(0.005, 0.02)),
            detection_prob=float(u(0.80, 0.97)), detection_delay_s=float(u(0.2, 1.0)), recheck_s=float(u(1.0, 3.0)),
            lapse_prob=float(u(0.01, 0.08)), fatigue_per_episode=float(u(0.002, 0.01)),
            pad_centre_error_px=float(u(1.0, 3.0)), pad_size_weber=float(u(0.05, 0.12)), strategy=strategy)


def operator_named(name: str) -> OperatorTraits | None:
    """``H07`` (the default population) or ``H07p5`` (population seed 5); None for other names."""
    match = _NAME.fullmatch(name)
    if match is None:
        return None
    seed = POPULATION_SEED if match.group(2) is None else int(match.group(2))
    return OperatorPopulation(seed).participant(int(match.group(1)))


def perceived(obs: Observation, traits: OperatorTraits, rng: np.random.Generator) -> Observation:
    """What the person takes from the video and the HUD at this step."""
    pad = obs.pad
    if pad is not None:
        du, dv = rng.normal(0.0, traits.pad_centre_error_px, size=2)
        size = max(0.5, pad.radius_px * (1.0 + traits.pad_size_weber * float(rng.standard_normal())))
        pad = replace(pad, u_px=pad.u_px + float(du), v_px=pad.v_px + float(dv), radius_px=size)
    deg = math.radians(HUD_DEGREES)
    return replace(obs, pad=pad,
                   position_ned_m=_rounded(obs.position_ned_m, HUD_METRES),
                   velocity_ned_m_s=_rounded(obs.velocity_ned_m_s, HUD_SPEED),
                   attitude_rad=_rounded(obs.attitude_rad, deg),
                   rates_frd_rad_s=(0.0, 0.0, 0.0))  # nothing on the screen shows angular rates


def _rounded(values: tuple[float, float, float], step: float) -> tuple[float, float, float]:
    return (round(values[0] / step) * step, round(values[1] / step) * step, round(values[2] / step) * step)


class TakeOver:
    """When the person's hand is actually on the override, given what their judgement flags.

    ``flagged`` is the intervention rule on the perceived, delayed view. A flag starts an event:
    noticed with ``detection_prob`` after ``detection_delay_s`` plus a reaction time (or, missed,
    looked at again ``recheck_s`` later); letting go waits a reaction time. Times are in control
    steps of ``period_s``.
    """

    def __init__(self, traits: OperatorTraits, period_s: float, rng: np.random.Generator) -> None:
        self.t, self.period_s, self.rng = traits, period_s, rng
        self.holding = False
        self._due: int | None = None  # step at which the pending take-over or let-go happens
        self._look_again: int | None = None  # after a miss: the step the person looks again
        self._step = 0
        self.missed = 0
        self.events = 0
        self.latencies_s: list[float] = []
        self._flag_step: int | None = None

    def _steps(self, seconds: float) -> int:
        return max(0, int(round(seconds / self.period_s)))

    def update(self, flagged: bool) -> bool:
        step, self._step = self._step, self._step + 1
        if self.holding:
            return self._letting_go(flagged, step)
        if not flagged:
            self._due = self._look_again = self._flag_step = None
            return False
        if self._flag_step is None:
            self._flag_step = step
        if self._look_again is not None:
            if step < self._look_again:
                return False
            self._look_again = None
        if self._due is None:
            self.events += 1
            if self.rng.random() < self.t.detection_prob:
                self._due = step + self._steps(self.t.detection_delay_s + self.t.draw_reaction_s(self.rng))
            else:
                self.missed += 1
                self._look_again = step + self._steps(self.t.recheck_s) + 1  # the flagged step after recheck_s
                return False
        if step >= self._due:
            self.holding, self._due = True, None
            self.latencies_s.append((step - self._flag_step) * self.period_s)
            self._flag_step = None
        return self.holding

    def _letting_go(self, flagged: bool, step: int) -> bool:
        if flagged:
            self._due = None
            return True
        if self._due is None:
            self._due = step + self._steps(self.t.draw_reaction_s(self.rng))
        if step >= self._due:
            self.holding, self._due = False, None
        return self.holding


class HumanOperatorPilot(HumanInput):
    """The scripted expert's sticks and intervention rule, seen, delayed, moved and tired like a person."""

    def __init__(self, traits: OperatorTraits, cfg: PilotConfig, control_rate_hz: float, trial_seed: int = 0,
                 inner: HumanInput | None = None) -> None:
        """``inner``: whose sticks and judgement the person has (default: the scripted expert
        under the person's strategy; tests pass their own)."""
        self.base = traits
        self.cfg = cfg
        self.period_s = 1.0 / control_rate_hz
        self.trial_seed = trial_seed
        self.expert = inner if inner is not None else InterveningExpert(traits.strategy.pilot_config(cfg))
        self._resets = 0
        self._begin(0)

    def _begin(self, episode: int) -> None:
        self.episode = episode
        self.traits = self.base.at_episode(episode)
        self.rng = np.random.default_rng([self.base.seed, self.trial_seed, episode])
        delay = int(round(self.traits.perception_delay_s / self.period_s))
        self._seen: deque[Observation] = deque(maxlen=delay + 1)
        self.takeover = TakeOver(self.traits, self.period_s, self.rng)
        self._stick = np.zeros(4)
        self._last: HumanCommand | None = None
        self.lapses = 0

    def reset(self) -> None:
        self._begin(self._resets)
        self._resets += 1
        self.expert.reset()

    def read(self, obs: Observation) -> HumanCommand:
        self._seen.append(perceived(obs, self.traits, self.rng))
        if self._last is not None and self.rng.random() < self.traits.lapse_prob:
            self.lapses += 1
            return self._last
        judged = self.expert.read(self._seen[0])  # what the person makes of what they saw, delay ago
        holding = self.takeover.update(judged.override_held)
        self._last = HumanCommand(self._hand(judged.command), holding)
        return self._last

    def _hand(self, wanted: JoystickCommand) -> JoystickCommand:
        """The stick after the neuromuscular lag, with remnant noise proportional to it."""
        u = wanted.to_array()
        alpha = 1.0 - math.exp(-self.period_s / self.traits.neuromuscular_lag_s) if self.traits.neuromuscular_lag_s > 0 else 1.0
        self._stick = self._stick + alpha * (u - self._stick)
        std = self.traits.remnant_ratio * np.abs(self._stick) + self.traits.remnant_floor
        return JoystickCommand.from_array(np.clip(self._stick + self.rng.normal(0.0, 1.0, 4) * std, -1.0, 1.0))


def operator_pilot(traits: OperatorTraits, cfg: PilotConfig, control_rate_hz: float, trial_seed: int = 0) -> HumanOperatorPilot:
    """Participant ``traits`` flying the scripted expert under their own strategy."""
    return HumanOperatorPilot(traits, cfg, control_rate_hz, trial_seed)
