"""Synthetic participants: the scripted expert with a person's imperfections.

The paper's four participants differed in skill. A :class:`PilotProfile` describes one
stand-in with four imperfections, each applied by :class:`SyntheticPilot` around an expert
(:class:`~companion.inputs.expert.InterveningExpert`, whose sticks serve demonstrations and
whose rule decides interventions):

- **reaction delay**: the pilot acts on the observation ``reaction_delay_steps`` control
  steps old (at 10.5 Hz one step is 95 ms); the take-over decision is equally late;
- **stick noise**: Gaussian noise of ``stick_noise_std`` (roll, pitch, yaw, throttle) added
  to every new command, then clipped to [-1, 1];
- **limited attention**: with probability ``attention_lapse_prob`` per step the pilot does not
  look: the last command (sticks and trigger) is held and the expert's memory does not advance;
- **patience**: the intervention rule's take-over thresholds are scaled by ``patience``
  (> 1 waits longer before taking over, < 1 takes over sooner).

And a strategy, as people differ in more than noise: how far ahead they see a miss coming
(``anticipation_s``, ``miss_margin_m``), how hard they correct (``correction_gain``) and how
they approach (``descent_scale``). Labels depend only on what the pilot sees (and its delay):
the expert's trim starts from zero at every take-over.

Randomness comes from a generator seeded by (profile seed, trial seed, episode), so a trial
is reproducible and the episodes of a trial differ.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from companion.config import PilotConfig
from companion.errors import ConfigError
from companion.inputs.base import HelpRequest, HumanCommand, HumanInput
from companion.inputs.expert import InterveningExpert
from companion.msg.command import JoystickCommand

if TYPE_CHECKING:
    from companion.msg.observation import Observation

MAX_DELAY_STEPS = 20
PATIENCE_RANGE = (0.25, 4.0)
EDGE_FRACTION_MAX = 0.98  # a pad further out is (partly) off screen: no later take-over exists


@dataclass(frozen=True)
class PilotProfile:
    """One synthetic participant's imperfections (see the module docstring)."""

    name: str
    seed: int
    reaction_delay_steps: int
    stick_noise_std: tuple[float, float, float, float]
    attention_lapse_prob: float
    patience: float
    description: str = ""
    anticipation_s: float = 3.0
    """How far ahead the person projects the touchdown (0: waits for visible trouble)."""
    miss_margin_m: float = 0.45
    """Projected touchdown this far from the pad's centre: take over."""
    correction_gain: float = 1.0
    """How hard they steer: scales the expert's offset gain and speed damping."""
    descent_scale: float = 1.0
    """How they approach: scales the expert's fast descent (< 1 cautious, > 1 brisk)."""

    def __post_init__(self) -> None:
        if not self.name or not self.name.isidentifier():
            raise ConfigError(f"pilot profile name must be a short identifier like 'P1', got {self.name!r}")
        if not isinstance(self.seed, int) or self.seed < 0:
            raise ConfigError(f"profile {self.name}: seed must be an integer >= 0, got {self.seed!r}")
        if not isinstance(self.reaction_delay_steps, int) or not 0 <= self.reaction_delay_steps <= MAX_DELAY_STEPS:
            raise ConfigError(f"profile {self.name}: reaction_delay_steps must be an integer in "
                              f"[0, {MAX_DELAY_STEPS}] control steps, got {self.reaction_delay_steps!r}")
        noise = tuple(float(s) for s in self.stick_noise_std)
        if len(noise) != 4 or not all(math.isfinite(s) and 0.0 <= s <= 1.0 for s in noise):
            raise ConfigError(f"profile {self.name}: stick_noise_std needs 4 values in [0, 1] "
                              f"(roll, pitch, yaw, throttle), got {self.stick_noise_std!r}")
        object.__setattr__(self, "stick_noise_std", noise)
        if not 0.0 <= self.attention_lapse_prob < 1.0:
            raise ConfigError(f"profile {self.name}: attention_lapse_prob must be in [0, 1), "
                              f"got {self.attention_lapse_prob!r}")
        lo, hi = PATIENCE_RANGE
        if not lo <= self.patience <= hi:
            raise ConfigError(f"profile {self.name}: patience must be in [{lo}, {hi}], got {self.patience!r}")
        self._check_strategy()

    def _check_strategy(self) -> None:
        ranges = {"anticipation_s": (0.0, 10.0), "miss_margin_m": (0.05, 3.0),
                  "correction_gain": (0.25, 3.0), "descent_scale": (0.25, 1.25)}
        for name, (lo, hi) in ranges.items():
            value = getattr(self, name)
            if not (isinstance(value, int | float) and lo <= value <= hi):
                raise ConfigError(f"profile {self.name}: {name} must be in [{lo}, {hi}], got {value!r}")

    def episode_rng(self, trial_seed: int, episode: int) -> np.random.Generator:
        """The pilot's randomness for one episode of one trial."""
        return np.random.default_rng([self.seed, trial_seed, episode])

    def pilot_config(self, base: PilotConfig) -> PilotConfig:
        """``base`` flown with this person's strategy (anticipation, correction, approach) and
        take-over thresholds scaled by patience (release ones kept below)."""
        p = self.patience
        edge = min(base.takeover_edge_fraction * p, EDGE_FRACTION_MAX)
        off_centre = base.takeover_off_centre_m * p
        return base.model_copy(update={
            "anticipation_s": self.anticipation_s,
            "takeover_predicted_miss_m": self.miss_margin_m,
            "xy_gain_per_m": base.xy_gain_per_m * self.correction_gain,
            "xy_damping_per_m_s": base.xy_damping_per_m_s * self.correction_gain,
            "descent_stick_fast": min(1.0, base.descent_stick_fast * self.descent_scale),
            "takeover_low_descent_m_s": base.takeover_low_descent_m_s * p,
            "takeover_edge_fraction": edge,
            "takeover_off_centre_m": off_centre,
            "takeover_descent_m_s": base.takeover_descent_m_s * p,
            "takeover_touchdown_speed_m_s": base.takeover_touchdown_speed_m_s * p,
            "takeover_stall_s": base.takeover_stall_s * p,
            "release_edge_fraction": min(base.release_edge_fraction, edge),
            "release_off_centre_m": min(base.release_off_centre_m, off_centre),
        })


PROFILES: dict[str, PilotProfile] = {
    p.name: p
    for p in (
        PilotProfile("P1", 101, 1, (0.02, 0.02, 0.01, 0.02), 0.02, 1.0,
                     "experienced: 95 ms reaction, steady hands, rarely looks away; sees a miss "
                     "coming 3 s ahead, firm corrections, even approach",
                     anticipation_s=3.0, miss_margin_m=0.4, correction_gain=1.0, descent_scale=1.0),
        PilotProfile("P2", 202, 2, (0.05, 0.05, 0.02, 0.04), 0.05, 1.2,
                     "skilled: 190 ms reaction, a little patient; lets the agent try (2 s ahead, "
                     "wider margin), gentle corrections, brisk approach",
                     anticipation_s=2.0, miss_margin_m=0.55, correction_gain=0.8, descent_scale=1.1),
        PilotProfile("P3", 303, 3, (0.08, 0.08, 0.03, 0.06), 0.10, 0.8,
                     "average: 286 ms reaction, eager: takes over early (4 s ahead, tight margin) "
                     "and over-corrects, cautious approach",
                     anticipation_s=4.0, miss_margin_m=0.3, correction_gain=1.3, descent_scale=0.8),
        PilotProfile("P4", 404, 4, (0.12, 0.12, 0.05, 0.10), 0.15, 1.5,
                     "novice: 381 ms reaction, shaky, often distracted; notices a miss late "
                     "(1 s ahead, wide margin), weak corrections, hurried approach",
                     anticipation_s=1.0, miss_margin_m=0.7, correction_gain=0.7, descent_scale=1.2),
    )
}
"""The four named participants, from most to least skilled."""


def profile_named(name: str) -> PilotProfile:
    """A named profile (P1-P4), with an error that lists the names."""
    try:
        return PROFILES[name]
    except KeyError:
        raise ConfigError(f"unknown synthetic pilot {name!r}; use one of {', '.join(PROFILES)}") from None


class SyntheticPilot(HumanInput):
    """A profile's imperfections around an inner source (normally :class:`InterveningExpert`).

    Episode ``k`` of a trial (counted by :meth:`reset`, which the session calls at every start)
    draws from ``profile.episode_rng(trial_seed, k)``.
    """

    def __init__(self, profile: PilotProfile, inner: HumanInput, trial_seed: int = 0) -> None:
        self.profile = profile
        self.inner = inner
        self.trial_seed = trial_seed
        self._resets = 0
        self._begin(0)

    def _begin(self, episode: int) -> None:
        self.episode = episode
        self.rng = self.profile.episode_rng(self.trial_seed, episode)
        self._seen: deque[Observation] = deque(maxlen=self.profile.reaction_delay_steps + 1)
        self._last: HumanCommand | None = None
        self.lapses = 0

    def reset(self) -> None:
        self._begin(self._resets)
        self._resets += 1
        self.inner.reset()

    def close(self) -> None:
        self.inner.close()

    def look_again(self) -> None:
        """Turn back to the screen after looking away for a while: what was seen before is
        forgotten (the delay line, the last command, the inner pilot's memory); the episode's
        randomness goes on."""
        self._seen.clear()
        self._last = None
        self.inner.reset()

    def read(self, obs: Observation) -> HumanCommand:
        self._seen.append(obs)
        looking_away = self.rng.random() < self.profile.attention_lapse_prob
        if looking_away and self._last is not None:
            self.lapses += 1
            return self._last
        answer = self.inner.read(self._seen[0])  # the oldest kept: reaction_delay_steps ago
        self._last = HumanCommand(self._noisy(answer.command), answer.override_held)
        return self._last

    def _noisy(self, command: JoystickCommand) -> JoystickCommand:
        noise = self.rng.normal(0.0, self.profile.stick_noise_std)
        return JoystickCommand.from_array(np.clip(command.to_array() + noise, -1.0, 1.0))


def synthetic_pilot(profile: PilotProfile, cfg: PilotConfig, trial_seed: int = 0) -> SyntheticPilot:
    """The participant ``profile`` flying the scripted expert under its patience-scaled rule."""
    return SyntheticPilot(profile, InterveningExpert(profile.pilot_config(cfg)), trial_seed)


class OnCallPilot(HumanInput):
    """A participant who watches only when the companion asks (``robot_gated``).

    Between requests they are away: the session does not read them in intervention
    episodes. A request reaches them (:meth:`on_request`); ``response_steps`` control steps
    later they have turned to the screen and take over at once (the vehicle is holding, which
    is why they were asked), fly as the participant does, and let go by the participant's
    release rule; then they are away again. Demonstrations are flown as usual.
    """

    robot_gated = True

    def __init__(self, pilot: SyntheticPilot, response_steps: int) -> None:
        if not isinstance(pilot.inner, InterveningExpert):
            raise ConfigError("an on-call participant needs the scripted expert with its intervention rule")
        if response_steps < 0:
            raise ConfigError(f"response_steps must be >= 0, got {response_steps}")
        self.pilot = pilot
        self.expert = pilot.inner
        self.response_steps = response_steps
        self._state = "away"
        self._wait = 0
        self.answered = 0

    def reset(self) -> None:
        self.pilot.reset()
        self._state, self._wait = "away", 0

    def close(self) -> None:
        self.pilot.close()

    def on_request(self, request: HelpRequest | None) -> None:
        if request is not None and self._state == "away":
            self._state, self._wait = "responding", self.response_steps

    def read(self, obs: Observation) -> HumanCommand:
        if self._state == "responding":
            if self._wait > 0:
                self._wait -= 1
                return HumanCommand.neutral()
            self.pilot.look_again()
            self.expert.take_over_now()
            self._state = "flying"
            self.answered += 1
        command = self.pilot.read(obs)
        if self._state == "flying" and not command.override_held:
            self._state = "away"
        return command


def on_call_pilot(profile: PilotProfile, cfg: PilotConfig, trial_seed: int, response_steps: int) -> OnCallPilot:
    """The participant ``profile``, watching only when asked, answering ``response_steps`` late."""
    return OnCallPilot(synthetic_pilot(profile, cfg, trial_seed), response_steps)
