"""Symmetry augmentation: every sample and its left/right mirror image.

The diagnosis (docs/learner.md, "What the diagnosis found") ranks coverage first: the policies
fail on states further from their training data than where they land. The task is symmetric
about the vertical plane through the pad along north (the ground vehicle is a box with its long
side along north, the starts are uniform in a square about the pad, the wind's direction is
random per episode, the camera's principal point is the image centre): a person who flew a
state would have flown its mirror image with the mirrored sticks. So the mirrored sample is as
good a label as the recorded one, on a state the person never showed.

The mirror is the reflection ``east -> -east`` of the world. What changes sign, in the
observation (``companion/msg/observation.py``, :data:`OBS_NAMES`): the east position and
velocity, roll and roll rate ``p`` (the body's right goes to its left), yaw and yaw rate ``r``
(clockwise becomes anticlockwise) and the pad's image column ``pad_u`` (the image is mirrored
about its centre column, ``cx = (width - 1) / 2``); in the action (``roll, pitch, yaw,
throttle``): the roll stick (move right) and the yaw stick (turn clockwise). North, down,
pitch, ``q``, the velocities north and down, ``pad_v``, ``pad_radius`` (-1 for "not visible"
stays -1), pitch and throttle sticks stay. The normalised yaw lies in [-1, 1); its mirror is
wrapped back into that range, so mirroring twice gives every sample back bit for bit.

Only the training minibatches are mirrored: the policy flies the observation as it is, so
nothing of this travels with a checkpoint.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from companion.errors import ConfigError
from companion.msg.command import ACTION_NAMES
from companion.msg.observation import OBS_NAMES

MIRRORED_OBS: frozenset[str] = frozenset(
    {"east_m", "roll_rad", "yaw_rad", "ve_m_s", "p_rad_s", "r_rad_s", "pad_u"})
"""Observation entries whose sign a left/right mirror flips."""
KEPT_OBS: frozenset[str] = frozenset(
    {"north_m", "down_m", "pitch_rad", "vn_m_s", "vd_m_s", "q_rad_s", "pad_v", "pad_radius"})
"""Observation entries a left/right mirror leaves as they are."""
MIRRORED_ACTIONS: frozenset[str] = frozenset({"roll", "yaw"})
"""Sticks whose sign a left/right mirror flips (roll +1 = move right, yaw +1 = clockwise)."""
KEPT_ACTIONS: frozenset[str] = frozenset({"pitch", "throttle"})
WRAPPED_OBS = "yaw_rad"
"""The one entry that is an angle normalised into [-1, 1): its mirror is wrapped back."""


def mirror_signs(names: Sequence[str], flipped: frozenset[str], kept: frozenset[str]) -> np.ndarray:
    """+1/-1 per column, -1 for the names in ``flipped``; a name in neither set (a layout this
    module does not know) raises ConfigError, so a new observation cannot be mirrored wrongly."""
    unknown = [n for n in names if n not in flipped | kept]
    if unknown:
        raise ConfigError(f"mirror_augment does not know how {unknown} transform under a left/right "
                          "mirror; add them to companion/learning/augment.py or set mirror_augment = false")
    return np.array([-1.0 if n in flipped else 1.0 for n in names], np.float32)


class Mirror:
    """The left/right mirror of one observation layout and the joystick's actions."""

    def __init__(self, obs_names: Sequence[str] = OBS_NAMES) -> None:
        self.obs_signs = mirror_signs(obs_names, MIRRORED_OBS, KEPT_OBS)
        self.action_signs = mirror_signs(ACTION_NAMES, MIRRORED_ACTIONS, KEPT_ACTIONS)
        self._yaw = list(obs_names).index(WRAPPED_OBS) if WRAPPED_OBS in obs_names else None

    def observations(self, obs: np.ndarray) -> np.ndarray:
        """The mirrored copies of ``(..., obs_dim)`` observations (float32, a new array)."""
        out = np.multiply(obs, self.obs_signs, dtype=np.float32)
        if self._yaw is not None:  # -(-1) = +1 is the angle -1 again: keep [-1, 1)
            yaw = out[..., self._yaw]
            yaw[yaw >= 1.0] -= np.float32(2.0)
        return out

    def actions(self, actions: np.ndarray) -> np.ndarray:
        """The mirrored copies of ``(..., 4)`` joystick actions."""
        return np.multiply(actions, self.action_signs, dtype=np.float32)

    def with_mirrored(self, obs: np.ndarray, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A minibatch followed by its mirror image, along the rows' axis (an ensemble's
        ``(K, n, ...)`` batches become ``(K, 2n, ...)``)."""
        return (np.concatenate([obs, self.observations(obs)], axis=-2),
                np.concatenate([actions, self.actions(actions)], axis=-2))
