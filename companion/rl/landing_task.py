"""The landing task as a reinforcement learner sees it, whichever env flies it.

Its actions are subsets of the sticks (the paper's PPO baselines), each value in [-1, 1], in
:data:`ACTION_AXES` order; an n-action task controls the first n:

* 2 -- (pitch, roll); throttle held at :data:`DESCENT_THROTTLE`, yaw 0;
* 3 -- (pitch, roll, throttle); yaw 0;
* 4 -- (pitch, roll, throttle, yaw).

Its observation is the paper's 15 values (:func:`observation_space`), its reward the one scoring
rule's (companion/control/outcome.py): sparse, 1 on a touchdown the SITL's ground truth judges
successful, else 0 (:func:`outcome_info`). :class:`~companion.rl.gym_env.LandingEnv` and
:class:`~companion.rl.batched_env.BatchedLandingEnv` both fly it.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from companion.control import outcome as outcome_rule
from companion.errors import ConfigError
from companion.msg.observation import OBS_DIM, PAD_CENTRE_CLIP, PAD_RADIUS_CLIP

ACTION_AXES: tuple[str, ...] = ("pitch", "roll", "throttle", "yaw")
"""What the action's entries control, in order; an n-action env controls the first n."""
DESCENT_THROTTLE = -0.5
"""Constant throttle stick of the 2-action task: about 0.47 m/s down with the default
commands (deadband 0.05, v_z_max 1 m/s), 8 m to the pad in about 180 steps."""


def check_task(action_dims: int, descent_throttle: float) -> None:
    """The task's settings: ConfigError naming what is wrong."""
    if action_dims not in (2, 3, 4):
        raise ConfigError(f"action_dims must be 2 (pitch, roll), 3 (+ throttle) or 4 (+ yaw), got {action_dims}")
    if not -1.0 <= descent_throttle <= 0.0:
        raise ConfigError(f"descent_throttle is a stick value in [-1, 0] (down), got {descent_throttle}")


def observation_space() -> gym.spaces.Box:
    """Telemetry is never clipped (unbounded); the pad's three values have documented ranges."""
    low = np.full(OBS_DIM, -np.inf, dtype=np.float32)
    high = np.full(OBS_DIM, np.inf, dtype=np.float32)
    low[-3:] = (-PAD_CENTRE_CLIP, -PAD_CENTRE_CLIP, -1.0)
    high[-3:] = (PAD_CENTRE_CLIP, PAD_CENTRE_CLIP, PAD_RADIUS_CLIP)
    return gym.spaces.Box(low, high, dtype=np.float32)


def stick_values(action: np.ndarray, action_dims: int, descent_throttle: float) -> np.ndarray:
    """An action of ``action_dims`` values -> the four sticks (roll, pitch, yaw, throttle)."""
    a = np.asarray(action, dtype=np.float64).reshape(-1)
    if a.shape != (action_dims,):
        raise ValueError(f"expected an action of {action_dims} values {ACTION_AXES[:action_dims]}, got shape {a.shape}")
    return stick_rows(a[None, :], descent_throttle)[0]


def stick_rows(actions: np.ndarray, descent_throttle: float) -> np.ndarray:
    """Actions ``(n, action_dims)`` (float64) -> sticks ``(n, 4)`` (roll, pitch, yaw, throttle):
    the values are copied, so a row is the same as that action alone (the batched env's)."""
    n, action_dims = actions.shape
    sticks = np.empty((n, 4))
    sticks[:, 0], sticks[:, 1] = actions[:, 1], actions[:, 0]  # roll, pitch
    sticks[:, 2] = actions[:, 3] if action_dims == 4 else 0.0
    sticks[:, 3] = actions[:, 2] if action_dims >= 3 else descent_throttle
    return sticks


def outcome_info(seed: int | None, steps: int, outcome: str | None,
                 result: outcome_rule.Score) -> tuple[dict[str, Any], float]:
    """A step's info and reward, ``result`` scored by the one rule."""
    return ({"seed": seed, "steps": steps, "outcome": outcome, "success": bool(result.success),
             "touchdown_distance_m": result.distance_m}, result.reward)
