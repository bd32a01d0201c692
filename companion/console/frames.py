"""The camera for the page: each new frame as a JPEG with a small header, on its own thread.

The pump watches the run's camera source (the same one the observer reads) every few
milliseconds, so the page sees every frame the camera delivers, not only the control loop's. Message layout (little-endian):
frame_number u32, time_boot_ms u32, wall time when encoded in ms since the epoch f64, then
the JPEG bytes.
"""

from __future__ import annotations

import logging
import struct
import threading
import time
from collections.abc import Callable

import cv2

from colcommon.frames import Frame
from companion.vision.camera import CameraSource

log = logging.getLogger(__name__)
FRAME_HEADER = struct.Struct("<IId")


def encode_for_page(frame: Frame, jpeg_quality: int = 80, wall_ms: float | None = None) -> bytes:
    """Header + JPEG of one frame."""
    ok, buf = cv2.imencode(".jpg", frame.image, [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)])
    if not ok:
        raise ValueError("JPEG encoding of a camera frame failed")
    stamp = time.time() * 1000.0 if wall_ms is None else wall_ms
    return FRAME_HEADER.pack(frame.frame_number % 2**32, frame.time_boot_ms % 2**32, stamp) + buf.tobytes()


def decode_header(message: bytes) -> tuple[int, int, float]:
    """(frame_number, time_boot_ms, wall_ms) of a page frame message."""
    return FRAME_HEADER.unpack_from(message)


class FramePump:
    """Hands every new frame of ``camera`` to ``on_frame`` (already encoded) until stopped."""

    def __init__(self, camera: CameraSource, on_frame: Callable[[Frame, bytes], None],
                 jpeg_quality: int = 80, poll_s: float = 0.004) -> None:
        self.camera, self.on_frame = camera, on_frame
        self.jpeg_quality, self.poll_s = jpeg_quality, poll_s
        self.frames = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="console-frames", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self, timeout_s: float = 2.0) -> None:
        self._stop.set()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(timeout_s)

    def _next(self, last: Frame | None) -> Frame | None:
        """The camera's newest frame if it is not ``last`` (polling never waits inside the
        source, whose waits would warn of frames the control loop did not ask for)."""
        frame = self.camera.latest()
        if frame is None or (last is not None and frame.frame_number == last.frame_number):
            return None
        return frame

    def _run(self) -> None:
        last: Frame | None = None
        while not self._stop.is_set():
            frame = self._next(last)
            if frame is None:
                self._stop.wait(self.poll_s)
                continue
            last = frame
            try:
                self.on_frame(frame, encode_for_page(frame, self.jpeg_quality))
                self.frames += 1
            except Exception:  # a viewer's problem must never stop the pump
                log.exception("could not hand a camera frame to the console")
