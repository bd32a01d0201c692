"""Noise in what the vehicle flies while the person demonstrates (DART, Laskey et al. 2017).

Why: a policy cloned from clean demonstrations meets states no demonstration visited (the
diagnosis's first cause, docs/learner.md) and has never seen how to recover from them. With this
on, each demonstration step the vehicle flies the person's sticks plus Gaussian noise, so the
person's next commands correct a perturbed state; the recorded label stays what the person
commanded, never the noisy command. Interventions and the policy's own steps are never
perturbed.
"""

from __future__ import annotations

import numpy as np

from companion.msg.command import JoystickCommand


class DemoNoise:
    """Seeded stick noise for demonstration steps, a stream per episode (same seed, same noise)."""

    def __init__(self, std: float, seed: int) -> None:
        if not np.isfinite(std) or std < 0:
            raise ValueError(f"demonstration noise std must be finite and >= 0, got {std!r}")
        self.std, self.seed = std, seed
        self._rng = np.random.default_rng([seed, 0])

    def begin(self, episode: int) -> None:
        """A new episode's stream: depends on the seed and the episode only, not on what ran before."""
        self._rng = np.random.default_rng([self.seed, episode])

    def flown(self, command: JoystickCommand) -> JoystickCommand:
        """The command the vehicle flies: each stick plus N(0, std), kept within [-1, 1]."""
        noisy = command.to_array() + self._rng.normal(0.0, self.std, 4)
        return JoystickCommand.from_array(np.clip(noisy, -1.0, 1.0))
