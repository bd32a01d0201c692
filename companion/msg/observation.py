"""The paper's 15-value observation: one order, one normalisation, one "pad not visible" code.

Every consumer (session, dataset, policy, gym env) builds its vector with
:meth:`Observation.to_vector` (the batched env, for many at once, with the functions it uses,
:func:`pad_features` and :func:`normalised`) and names columns with :data:`OBS_NAMES`; nothing
else may normalise telemetry or encode the pad. The vector, in order (value = raw / scale):

====  ======================  =========================================================
 #    name                    normalisation
====  ======================  =========================================================
0-2   north_m, east_m, down_m     local NED position / 10 m
3-5   roll_rad, pitch_rad, yaw_rad  / pi (yaw first wrapped to [-pi, pi))
6-8   vn_m_s, ve_m_s, vd_m_s      NED velocity / 5 m/s
9-11  p_rad_s, q_rad_s, r_rad_s   FRD body rates / pi rad/s
12    pad_u                   (u - cx) / (width / 2): -1 left edge, +1 right edge
13    pad_v                   (v - cy) / (height / 2): -1 top edge, +1 bottom edge
14    pad_radius              radius / (height / 2): 1 = the pad's diameter fills the height
====  ======================  =========================================================

``cx = (width - 1) / 2`` and ``cy = (height - 1) / 2`` (pixel centres at integers). A partly
visible pad's centre can be outside the image: ``pad_u`` and ``pad_v`` are clipped to
[-2, 2], ``pad_radius`` to [0, 2] (close to touchdown the pad is larger than the image).
Pad not visible: ``pad_u = pad_v = 0`` and ``pad_radius = -1`` (a visible pad always has a
positive radius, so the sign alone tells the two apart). Telemetry is never clipped.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from companion.msg.pad import PadDetection

OBS_NAMES: tuple[str, ...] = (
    "north_m", "east_m", "down_m",
    "roll_rad", "pitch_rad", "yaw_rad",
    "vn_m_s", "ve_m_s", "vd_m_s",
    "p_rad_s", "q_rad_s", "r_rad_s",
    "pad_u", "pad_v", "pad_radius",
)
OBS_DIM = len(OBS_NAMES)  # 15
POSITION_SCALE_M = 10.0
ANGLE_SCALE_RAD = math.pi
VELOCITY_SCALE_M_S = 5.0
RATE_SCALE_RAD_S = math.pi
PAD_CENTRE_CLIP = 2.0
PAD_RADIUS_CLIP = 2.0
PAD_NOT_VISIBLE: tuple[float, float, float] = (0.0, 0.0, -1.0)
# raw value / OBS_SCALES = normalised value, for the 12 telemetry entries.
OBS_SCALES: tuple[float, ...] = (POSITION_SCALE_M,) * 3 + (ANGLE_SCALE_RAD,) * 3 + (VELOCITY_SCALE_M_S,) * 3 + (RATE_SCALE_RAD_S,) * 3


def _triple(name: str, value: Sequence[float]) -> tuple[float, float, float]:
    values = tuple(float(v) for v in np.asarray(value, dtype=float).reshape(-1))
    if len(values) != 3:
        raise ValueError(f"{name} needs 3 values, got {len(values)}")
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f"{name} is not finite: {values}; drop this telemetry sample")
    return values  # type: ignore[return-value]


def wrap_angle_rad(angle_rad: float) -> float:
    """``angle`` in [-pi, pi)."""
    return (angle_rad + math.pi) % (2.0 * math.pi) - math.pi


@dataclass(frozen=True)
class Observation:
    """What the agent knows at one control step: telemetry plus the pad in the camera image."""

    position_ned_m: tuple[float, float, float]
    attitude_rad: tuple[float, float, float]
    velocity_ned_m_s: tuple[float, float, float]
    rates_frd_rad_s: tuple[float, float, float]
    pad: PadDetection | None
    image_size_px: tuple[int, int]  # (width, height)
    time_boot_ms: int
    frame_missing: bool = False
    """The configured camera gave no usable frame for this step: ``pad`` None then means
    "unknown", not "not visible", and the step is not a true sample (it is not recorded)."""

    def __post_init__(self) -> None:
        for name in ("position_ned_m", "attitude_rad", "velocity_ned_m_s", "rates_frd_rad_s"):
            object.__setattr__(self, name, _triple(name, getattr(self, name)))
        width, height = (int(x) for x in self.image_size_px)
        if width <= 0 or height <= 0:
            raise ValueError(f"image_size_px must be positive (width, height), got {self.image_size_px}")
        object.__setattr__(self, "image_size_px", (width, height))
        if self.pad is not None and not isinstance(self.pad, PadDetection):
            raise TypeError(f"pad must be a PadDetection or None, got {type(self.pad).__name__}")
        if int(self.time_boot_ms) < 0:
            raise ValueError(f"time_boot_ms must be >= 0, got {self.time_boot_ms}")

    def pad_features(self) -> tuple[float, float, float]:
        """The last three entries of the vector (see the module docstring)."""
        if self.pad is None:
            return PAD_NOT_VISIBLE
        u, v, r = pad_features(self.pad.u_px, self.pad.v_px, self.pad.radius_px, self.image_size_px)
        return (float(u), float(v), float(r))

    def to_vector(self) -> np.ndarray:
        """The normalised ``float32`` vector of length :data:`OBS_DIM`, in :data:`OBS_NAMES` order."""
        roll, pitch, yaw = self.attitude_rad
        telemetry = np.array(
            [*self.position_ned_m, roll, pitch, wrap_angle_rad(yaw), *self.velocity_ned_m_s, *self.rates_frd_rad_s]
        )
        vector = normalised(telemetry, self.pad_features())
        if not np.all(np.isfinite(vector)):  # overflow of huge but finite telemetry
            raise ValueError(f"observation vector is not finite: {vector}")
        return vector


def pad_features(u_px: ArrayLike, v_px: ArrayLike, radius_px: ArrayLike,
                 image_size_px: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A visible pad's three entries of the vector (see the module docstring), element by element:
    for one detection or for arrays of them (companion/rl/batched_env.py), the same values."""
    width, height = image_size_px
    u = (np.asarray(u_px) - (width - 1) / 2.0) / (width / 2.0)
    v = (np.asarray(v_px) - (height - 1) / 2.0) / (height / 2.0)
    r = np.asarray(radius_px) / (height / 2.0)
    clip = PAD_CENTRE_CLIP
    return np.clip(u, -clip, clip), np.clip(v, -clip, clip), np.clip(r, 0.0, PAD_RADIUS_CLIP)


def normalised(telemetry: np.ndarray, pad: ArrayLike) -> np.ndarray:
    """Raw telemetry ``(..., 12)`` in vector order (yaw already wrapped) and the pad's features
    ``(..., 3)`` -> the ``float32`` vectors ``(..., 15)``, element by element (a stack of them as
    each alone); not checked for overflow (:meth:`Observation.to_vector` checks)."""
    return np.concatenate([telemetry / np.array(OBS_SCALES), np.asarray(pad, dtype=np.float64)], axis=-1).astype(np.float32)


def pad_visible(vector: np.ndarray) -> bool:
    """Whether an observation vector (or the pad part of a dataset row) shows the pad."""
    return bool(np.asarray(vector)[OBS_DIM - 1] >= 0.0)
