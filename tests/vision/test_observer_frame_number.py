"""The observer says which camera frame each observation's pad came from (the console draws the
detection on that frame)."""

from __future__ import annotations

from colcommon.frames import Frame
from companion.vision.observer import Observer
from companion.vision.perception import PadDetector
from sitl.camera import CameraRenderer
from sitl.config import CameraConfig, WorldConfig
from sitl.world import World
from tests.vision.test_observer import StuckCamera, snapshot


def test_each_observation_names_its_frame_and_none_without_one() -> None:
    image = CameraRenderer(CameraConfig(), World(WorldConfig())).render((0.5, -0.3, -9.0), (0.0, 0.0, 0.0), 0.0)
    camera = StuckCamera(Frame(41, 1000, image))
    observer = Observer(camera, PadDetector(), (320, 240), frame_timeout_s=0.0)
    assert observer.observe(snapshot(1000), lockstep=True).pad is not None
    assert observer.last_frame_number == 41
    camera.frame = Frame(42, 1028, image)
    observer.observe(snapshot(1028), lockstep=True)
    assert observer.last_frame_number == 42
    observer.observe(snapshot(2000), lockstep=True)  # no frame of that step
    assert observer.last_frame_number is None
