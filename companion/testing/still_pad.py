"""A video of the pad seen from straight above, the same frame throughout: a camera for a real
autopilot's SITL, which has none (PX4 SIH and ArduCopter SITL render nothing).

The pad does not move in the picture whatever the vehicle does, so a pilot that watches it sees
a pad centred below at a fixed apparent height: the expert then descends at the rate it flies at
that height, all the way down. That exercises take-off, the descent and touchdown on a real
autopilot; steering to the pad needs a camera driven by the vehicle's telemetry.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from sitl.camera import CameraRenderer
from sitl.config import CameraConfig, WorldConfig
from sitl.world import World


def pad_frame(height_above_pad_m: float, camera: CameraConfig | None = None,
              world: WorldConfig | None = None) -> np.ndarray:
    """One BGR frame of the pad from ``height_above_pad_m`` straight above its centre."""
    wcfg = world or WorldConfig()
    renderer = CameraRenderer(camera or CameraConfig(), World(wcfg))
    return renderer.render((0.0, 0.0, -wcfg.vehicle_height_m - height_above_pad_m), (0.0, 0.0, 0.0), 0.0)


def write_still_pad_video(path: Path, height_above_pad_m: float = 1.0, seconds: float = 300.0,
                          fps: float = 15.0) -> Path:
    """Write ``seconds`` of the same pad frame to ``path`` (MPEG-4 part 2: a still scene costs
    almost nothing after the first frame); returns ``path``."""
    if not (height_above_pad_m > 0 and seconds > 0 and fps > 0):
        raise ValueError(f"height, seconds and fps must be > 0, got {height_above_pad_m}, {seconds}, {fps}")
    frame = pad_frame(height_above_pad_m)
    size = (frame.shape[1], frame.shape[0])
    fourcc = cv2.VideoWriter.fourcc(*"mp4v")
    writer = cv2.VideoWriter(str(path), fourcc, fps, size)
    if not writer.isOpened():
        raise OSError(f"OpenCV cannot write an MPEG-4 video to {path}")
    try:
        for _ in range(int(seconds * fps)):
            writer.write(frame)
    finally:
        writer.release()
    return path
