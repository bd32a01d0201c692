"""One frame of telemetry and one camera image become one observation.

The camera may be missing or dead during flight: then the pad is "not visible" to the policy and
a warning is logged (rate-limited), never a crash; the observation says its frame was missing,
so the step is not recorded as a sample (the pad's state is unknown, not "not visible"). In lockstep the image of frame T is asked for by its
stamp, so the agent decides step T on what the camera saw at T.
"""

from __future__ import annotations

import logging
import time
from collections import deque

from colcommon.frames import Frame
from companion.msg.observation import Observation
from companion.msg.pad import PadDetection
from companion.msg.snapshot import VehicleSnapshot
from companion.vision.camera import CameraSource, lockstep_frame
from companion.vision.perception import PadDetector

log = logging.getLogger(__name__)
WARN_EVERY_S = 5.0
STALE_AFTER_TICKS = 3  # the camera runs at least at the control rate
AGES_KEPT = 10_000


class Observer:
    """Builds observations from link snapshots and camera frames."""

    def __init__(self, camera: CameraSource | None, detector: PadDetector, image_size_px: tuple[int, int],
                 frame_timeout_s: float = 0.2) -> None:
        self.camera = camera
        self.detector = detector
        self.image_size_px = image_size_px
        self.frame_timeout_s = frame_timeout_s
        self.frames_missing = 0
        self.detect_errors = 0
        self.frames_stale = 0
        self._last_frame_number: int | None = None
        self._repeats = 0
        self._last_warning_s = -WARN_EVERY_S
        self.frame_ages_ms: deque[int] = deque(maxlen=AGES_KEPT)
        """Per observation: the vehicle's time of the telemetry minus the frame's stamp (the
        telemetry time it was rendered from, or its capture time): how old the picture is."""
        self._last_frame_ms: int | None = None
        self.last_frame_number: int | None = None
        """The number of the frame the latest observation's pad came from (None: no frame),
        so a viewer can draw the detection on that very frame."""

    def _warn(self, message: str) -> None:
        now = time.monotonic()
        if now - self._last_warning_s >= WARN_EVERY_S:
            self._last_warning_s = now
            log.warning("%s (pad counted as not visible; %d frames so far)", message, self.frames_missing)

    def detect(self, time_boot_ms: int | None) -> PadDetection | None:
        """The pad in the frame stamped ``time_boot_ms`` (or the newest frame), or None."""
        if self.camera is None:
            self.frames_missing += 1
            return None
        if time_boot_ms is None:
            frame = self._fresh(self.camera.latest())
        else:
            frame = lockstep_frame(self.camera, time_boot_ms, self.frame_timeout_s)
        if frame is None:
            self.frames_missing += 1
            self._warn("no camera frame for this control step")
            return None
        self.image_size_px = (frame.image.shape[1], frame.image.shape[0])
        self._last_frame_ms = frame.time_boot_ms
        self.last_frame_number = frame.frame_number
        try:
            return self.detector.detect(frame.image)
        except ValueError as exc:  # a corrupt image: judged not visible
            self.detect_errors += 1
            self._warn(f"camera frame unusable: {exc}")
            return None

    def _fresh(self, frame: Frame | None) -> Frame | None:
        """Real time: a stream that stays connected but stops sending keeps handing out its
        last frame; after STALE_AFTER_TICKS control steps with no new frame, that is no frame."""
        if frame is None:
            return None
        if frame.frame_number == self._last_frame_number:
            self._repeats += 1
            if self._repeats >= STALE_AFTER_TICKS:
                self.frames_stale += 1
                return None
        else:
            self._last_frame_number, self._repeats = frame.frame_number, 0
        return frame

    def observe(self, snapshot: VehicleSnapshot, lockstep: bool,
                position_ned_m: tuple[float, float, float] | None = None) -> Observation:
        """The observation for ``snapshot``; ValueError if its telemetry is not finite.
        ``position_ned_m``: the position relative to home (default: the snapshot's, as sent)."""
        stamp = snapshot.frame_time_boot_ms if lockstep else None
        self._last_frame_ms = self.last_frame_number = None
        missing_before = self.frames_missing + self.detect_errors
        pad = self.detect(stamp)
        frame_missing = self.camera is not None and self.frames_missing + self.detect_errors > missing_before
        if self._last_frame_ms is not None and getattr(self.camera, "vehicle_time_stamps", False):
            self.frame_ages_ms.append(int(snapshot.time_boot_ms) - self._last_frame_ms)
        return Observation(
            position_ned_m=snapshot.position_ned_m if position_ned_m is None else position_ned_m,
            attitude_rad=snapshot.attitude_rad,
            velocity_ned_m_s=snapshot.velocity_ned_m_s,
            rates_frd_rad_s=snapshot.rates_frd_rad_s,
            pad=pad,
            image_size_px=self.image_size_px,
            time_boot_ms=max(0, int(snapshot.frame_time_boot_ms if lockstep and snapshot.frame_time_boot_ms is not None else snapshot.time_boot_ms)),
            frame_missing=frame_missing,
        )
