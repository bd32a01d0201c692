"""The person's sample: the observation they saw and the joystick command they gave."""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

import numpy as np

from companion.msg.command import ACT_DIM, ACTION_NAMES


class Source(str, Enum):
    """Who produced a sample: the person flew the whole episode, or took over from the agent."""

    DEMONSTRATION = "demonstration"
    INTERVENTION = "intervention"


@dataclass(frozen=True)
class Sample:
    """One row: the observation the person saw and the joystick command they gave."""

    episode: int
    step: int
    time_s: float
    source: Source
    obs: np.ndarray
    action: np.ndarray

    def __post_init__(self) -> None:
        obs = np.array(self.obs, dtype=np.float32).reshape(-1)
        action = np.array(self.action, dtype=np.float32).reshape(-1)
        if action.shape != (ACT_DIM,):
            raise ValueError(f"an action has {ACT_DIM} values {ACTION_NAMES}, got {action.shape}")
        if not (np.all(np.isfinite(obs)) and np.all(np.isfinite(action))):
            raise ValueError("refusing a non-finite sample: it would poison training")
        if np.any(np.abs(action) > 1.0):
            raise ValueError(f"actions must lie in [-1, 1], got {action.tolist()}")
        if self.episode < 0 or self.step < 0 or not np.isfinite(self.time_s):
            raise ValueError("episode and step must be >= 0 and time_s finite")
        object.__setattr__(self, "source", Source(self.source))
        object.__setattr__(self, "obs", obs)
        object.__setattr__(self, "action", action)
