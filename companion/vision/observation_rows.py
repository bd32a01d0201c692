"""Observation vectors for rows of vehicles at once (the batched env, the batched evaluation).

The session builds one :class:`~companion.msg.observation.Observation` per step and takes its
vector; the drivers that fly many vehicles in one process build the same vectors here from each
vehicle's snapshot and camera image, through the same element-by-element functions
(:func:`~companion.msg.observation.pad_features`,
:func:`~companion.msg.observation.normalised`), so a row is that vehicle's vector alone.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import numpy as np

from companion.msg.observation import PAD_NOT_VISIBLE, pad_features, wrap_angle_rad
from companion.msg.pad import PadDetection
from companion.msg.snapshot import VehicleSnapshot
from companion.vision.perception import PadDetector

log = logging.getLogger(__name__)


def detect_pad(detector: PadDetector, image: np.ndarray | None) -> PadDetection | None:
    """The observer's detection: None without a camera image, or for a corrupt one."""
    if image is None:
        return None
    try:
        return detector.detect(image)
    except ValueError as exc:
        log.warning("camera frame unusable: %s (pad counted as not visible)", exc)
        return None


def telemetry_row(snap: VehicleSnapshot | None,
                  position_ned_m: tuple[float, float, float] | None = None) -> tuple[float, ...]:
    """The 12 telemetry values of the vector, raw, in order (yaw wrapped), as ``Observation``;
    ``position_ned_m`` replaces the snapshot's position as ``Observer.observe``'s does (the
    session passes the position relative to home)."""
    assert snap is not None  # a lane is connected before it is observed
    roll, pitch, yaw = snap.attitude_rad
    position = snap.position_ned_m if position_ned_m is None else position_ned_m
    return (*position, roll, pitch, wrap_angle_rad(yaw), *snap.velocity_ned_m_s, *snap.rates_frd_rad_s)


def pad_rows(detections: Sequence[PadDetection | None], image_size_px: tuple[int, int]) -> np.ndarray:
    """The pad's three entries of the vector for each detection (None: not visible), ``(n, 3)``:
    :func:`~companion.msg.observation.pad_features` on the stack of the visible ones."""
    pads = np.tile(np.array(PAD_NOT_VISIBLE), (len(detections), 1))
    seen = [(row, pad) for row, pad in enumerate(detections) if pad is not None]
    if seen:
        rows = [row for row, _ in seen]
        u, v, r = (np.array([getattr(pad, name) for _, pad in seen]) for name in ("u_px", "v_px", "radius_px"))
        pads[rows] = np.column_stack(pad_features(u, v, r, image_size_px))
    return pads
