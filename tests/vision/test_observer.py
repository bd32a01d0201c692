"""Observation building: camera frames by stamp, missing and stale frames, bad telemetry."""

from __future__ import annotations

import math
import threading

import numpy as np
import pytest

from colcommon.frames import Frame
from companion.msg.observation import PAD_NOT_VISIBLE
from companion.msg.snapshot import VehicleSnapshot
from companion.vision.camera import LOCKSTEP_FRAME_PATIENCE_S, SitlCameraSource
from companion.vision.observer import STALE_AFTER_TICKS, Observer
from companion.vision.perception import PadDetector
from sitl.camera import CameraRenderer
from sitl.config import CameraConfig, WorldConfig
from sitl.frames import FrameServer
from sitl.world import World
from tests.conftest import wait_until


class StuckCamera:
    """A source that stays connected but keeps handing out one frame."""

    def __init__(self, frame: Frame) -> None:
        self.frame = frame

    def latest(self) -> Frame:
        return self.frame

    def frame_at(self, time_boot_ms: int, timeout_s: float) -> Frame | None:
        return self.frame if self.frame.time_boot_ms >= time_boot_ms else None


def snapshot(t_ms: int = 1000, velocity=(0.0, 0.0, 0.0)) -> VehicleSnapshot:  # type: ignore[no-untyped-def]
    return VehicleSnapshot(0.0, t_ms, t_ms, 1, "PX4", True, "OFFBOARD", "IN_AIR", (0.5, -0.3, -9.0), velocity,
                           (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0.0, True, True)


@pytest.fixture
def pad_frame() -> Frame:
    image = CameraRenderer(CameraConfig(), World(WorldConfig())).render((0.5, -0.3, -9.0), (0.0, 0.0, 0.0), 0.0)
    return Frame(7, 1000, image)


def test_lockstep_uses_the_frame_of_the_step_and_sees_the_pad(pad_frame: Frame) -> None:
    obs = Observer(StuckCamera(pad_frame), PadDetector(), (320, 240)).observe(snapshot(1000), lockstep=True)
    assert obs.pad is not None and obs.time_boot_ms == 1000
    late = Observer(StuckCamera(pad_frame), PadDetector(), (320, 240), frame_timeout_s=0.0)
    assert late.observe(snapshot(1095), lockstep=True).pad is None  # no frame of that step
    assert late.frames_missing == 1


def test_a_stream_that_stops_sending_is_no_longer_trusted(pad_frame: Frame) -> None:
    observer = Observer(StuckCamera(pad_frame), PadDetector(), (320, 240))
    seen = [observer.observe(snapshot(), lockstep=False).pad is not None for _ in range(STALE_AFTER_TICKS + 3)]
    assert seen[: STALE_AFTER_TICKS] == [True] * STALE_AFTER_TICKS
    assert not any(seen[STALE_AFTER_TICKS + 1 :])
    assert observer.frames_stale >= 2
    assert tuple(observer.observe(snapshot(), lockstep=False).to_vector()[-3:]) == pytest.approx(PAD_NOT_VISIBLE)


def test_no_camera_means_pad_not_visible_and_nan_telemetry_is_refused() -> None:
    observer = Observer(None, PadDetector(), (320, 240))
    assert observer.observe(snapshot(), lockstep=True).pad is None
    with pytest.raises(ValueError):
        observer.observe(snapshot(velocity=(math.nan, 0.0, 0.0)), lockstep=True)


def test_a_corrupt_image_counts_as_not_visible(pad_frame: Frame) -> None:
    class Broken(StuckCamera):
        def frame_at(self, time_boot_ms: int, timeout_s: float) -> Frame:
            return Frame(1, time_boot_ms, np.zeros((240, 320, 3), np.uint8))

    observer = Observer(Broken(pad_frame), PadDetector(), (320, 240))
    observer.detector.detect = lambda image: (_ for _ in ()).throw(ValueError("bad image"))  # type: ignore[method-assign]
    assert observer.observe(snapshot(), lockstep=True).pad is None
    assert observer.detect_errors == 1


def test_lockstep_waits_for_its_frame_longer_than_the_frame_timeout(pad_frame: Frame) -> None:
    """A lockstep frame is written before its marker, so it is on its way: the step waits for it
    (up to LOCKSTEP_FRAME_PATIENCE_S) even when it comes later than ``frame_timeout_s`` (a
    starved reader thread), and flies on its picture; in real time the newest frame is taken."""
    with FrameServer() as server:
        source = SitlCameraSource(server.uri)
        source.open()
        try:
            assert wait_until(lambda: server.client_count == 1)
            observer = Observer(source, PadDetector(), (320, 240), frame_timeout_s=0.0)
            late = threading.Timer(0.3, lambda: server.publish(pad_frame, blocking=True))
            late.start()
            obs = observer.observe(snapshot(1000), lockstep=True)
            late.join()
            assert obs.pad is not None and not obs.frame_missing and observer.frames_missing == 0
        finally:
            source.close()
    assert LOCKSTEP_FRAME_PATIENCE_S >= 10.0  # as long as the SITL waits for an answer at most
