"""The camera pump for the page: every new frame once, encoded with its header."""

from __future__ import annotations

import time

import cv2
import numpy as np

from colcommon.frames import Frame
from companion.console.frames import FramePump, decode_header, encode_for_page


class FakeCamera:
    def __init__(self) -> None:
        self.frame: Frame | None = None

    def open(self) -> None: ...

    def latest(self) -> Frame | None:
        return self.frame

    def frame_at(self, time_boot_ms: int, timeout_s: float) -> Frame | None:
        raise AssertionError("the pump must not wait inside the source")

    def close(self) -> None: ...


def frame(n: int) -> Frame:
    image = np.zeros((24, 32, 3), np.uint8)
    image[:, : n + 1] = 200
    return Frame(n, 1000 + n * 28, image)


def test_the_header_and_jpeg_round_trip() -> None:
    data = encode_for_page(frame(3), wall_ms=1234.5)
    assert decode_header(data) == (3, 1084, 1234.5)
    image = cv2.imdecode(np.frombuffer(data[16:], np.uint8), cv2.IMREAD_COLOR)
    assert image.shape == (24, 32, 3)


def test_each_new_frame_reaches_the_page_once() -> None:
    camera, seen = FakeCamera(), []
    pump = FramePump(camera, lambda f, data: seen.append((f.frame_number, decode_header(data)[0])))
    pump.start()
    try:
        for n in range(5):
            camera.frame = frame(n)
            deadline = time.monotonic() + 2.0
            while len(seen) < n + 1 and time.monotonic() < deadline:
                time.sleep(0.005)
        time.sleep(0.05)
    finally:
        pump.stop()
    assert seen == [(n, n) for n in range(5)] and pump.frames == 5
