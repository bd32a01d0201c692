"""The ArUco pad detector on rendered images: the pose it gives against the pose rendered."""

from __future__ import annotations

import numpy as np
import pytest

from companion.vision.aruco import ArucoPadDetector, PadPose
from sitl import pad_marker
from sitl.camera import CAM_FROM_BODY, CameraRenderer, camera_matrix, rotation_ned_from_body
from sitl.config import CameraConfig, WorldConfig
from sitl.world import World

MARKED = CameraConfig(pad_marker="aruco")


@pytest.fixture(scope="module")
def renderer() -> CameraRenderer:
    return CameraRenderer(MARKED, World(WorldConfig()))


@pytest.fixture(scope="module")
def detector() -> ArucoPadDetector:
    return ArucoPadDetector(camera_matrix(MARKED), (MARKED.width_px, MARKED.height_px))


def true_pose(renderer: CameraRenderer, position: np.ndarray, attitude: tuple[float, float, float]
              ) -> tuple[np.ndarray, np.ndarray]:
    """The pad centre and the pad-frame rotation in the camera frame, from the rendered pose."""
    pad = renderer.world.pad_ned(0.0)
    r_cam_ned = CAM_FROM_BODY @ rotation_ned_from_body(attitude).T
    return r_cam_ned @ (pad - position), r_cam_ned  # the pad frame is NED-aligned


def pose_at(renderer: CameraRenderer, detector: ArucoPadDetector, height_m: float, offset_ne: tuple[float, float],
            attitude: tuple[float, float, float]) -> tuple[PadPose | None, np.ndarray, np.ndarray]:
    pad = renderer.world.pad_ned(0.0)
    position = pad + np.array([offset_ne[0], offset_ne[1], -height_m])
    image = renderer.render(position, attitude, 0.0)
    t, r = true_pose(renderer, position, attitude)
    return detector.detect(image), t, r


def test_the_renderer_and_the_detector_share_one_camera_matrix(renderer: CameraRenderer) -> None:
    np.testing.assert_array_equal(camera_matrix(MARKED), renderer.K)


def test_the_board_fits_the_default_roof_and_its_markers_do_not_overlap() -> None:
    world = WorldConfig()
    pad_marker.check_fits(world.vehicle_length_m, world.vehicle_width_m)
    boxes = [(m.north_m - m.size_m, m.north_m, m.east_m, m.east_m + m.size_m) for m in pad_marker.MARKERS]
    for i, a in enumerate(boxes):
        for b in boxes[i + 1:]:
            apart = a[1] <= b[0] or b[1] <= a[0] or a[3] <= b[2] or b[3] <= a[2]
            assert apart, (a, b)
    with pytest.raises(ValueError, match="vehicle_width_m"):
        pad_marker.check_fits(4.0, 1.0)


@pytest.mark.parametrize(("height_m", "offset_ne", "attitude"), [
    (1.0, (0.0, 0.0), (0.0, 0.0, 0.0)),
    (1.0, (0.3, -0.2), (0.05, -0.08, 0.4)),
    (2.0, (-0.5, 0.4), (-0.1, 0.05, -1.2)),
    (3.0, (0.0, 0.0), (0.0, 0.0, 0.0)),
    (3.0, (1.0, -0.8), (0.08, 0.1, 2.5)),
])
def test_pose_error_is_a_few_centimetres_from_one_to_three_metres(
        renderer: CameraRenderer, detector: ArucoPadDetector, height_m: float,
        offset_ne: tuple[float, float], attitude: tuple[float, float, float]) -> None:
    pose, t, r = pose_at(renderer, detector, height_m, offset_ne, attitude)
    assert pose is not None
    error_m = float(np.linalg.norm(np.array(pose.position_cam_m) - t))
    assert error_m < 0.01 * height_m + 0.02, (error_m, pose.marker_ids)  # 3 cm at 1 m, 5 cm at 3 m
    angle = np.degrees(np.arccos(np.clip((np.trace(pose.rotation.T @ r) - 1) / 2, -1, 1)))
    assert angle < 3.0
    assert pose.reprojection_px < 1.0


@pytest.mark.parametrize(("height_m", "ids"), [(0.15, {0}), (0.6, {0}), (5.0, {1, 2, 3, 4}), (8.0, {5, 6})])
def test_the_board_is_read_from_the_start_height_down_to_touchdown(
        renderer: CameraRenderer, detector: ArucoPadDetector, height_m: float, ids: set[int]) -> None:
    """The centre marker near touchdown, the ring in between, the outer pair from the start."""
    pose, t, _ = pose_at(renderer, detector, height_m, (0.0, 0.0), (0.0, 0.0, 0.0))
    assert pose is not None
    assert ids <= set(pose.marker_ids)
    assert np.linalg.norm(np.array(pose.position_cam_m) - t) < 0.02 * height_m + 0.02


def test_no_board_no_pose(detector: ArucoPadDetector) -> None:
    plain = CameraRenderer(CameraConfig(), World(WorldConfig()))
    image = plain.render(plain.world.pad_ned(0.0) + np.array([0.0, 0.0, -2.0]), (0.0, 0.0, 0.0), 0.0)
    assert detector.detect(image) is None
    assert detector.detect(np.zeros((240, 320, 3), np.uint8)) is None


def test_the_colour_pad_is_unchanged_unless_the_board_is_asked_for() -> None:
    world = World(WorldConfig())
    default = CameraRenderer(CameraConfig(), world)
    explicit = CameraRenderer(CameraConfig(pad_marker="none"), world)
    for a, b in zip(default.roof.levels, explicit.roof.levels, strict=True):
        np.testing.assert_array_equal(a, b)


def test_an_image_of_another_size_or_type_is_refused(detector: ArucoPadDetector) -> None:
    with pytest.raises(ValueError, match="intrinsics"):
        detector.detect(np.zeros((480, 640, 3), np.uint8))
    with pytest.raises(ValueError, match="BGR"):
        detector.detect(np.zeros((240, 320), np.uint8))
    with pytest.raises(ValueError, match="pinhole"):
        ArucoPadDetector(np.full((3, 3), np.nan), (320, 240))


def test_a_pose_must_be_finite_and_in_front() -> None:
    eye = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    with pytest.raises(ValueError, match="finite"):
        PadPose((0.0, float("nan"), 2.0), eye, (0,), ((1.0, 1.0),), 0.1)
    with pytest.raises(ValueError, match="in front"):
        PadPose((0.0, 0.0, -2.0), eye, (0,), ((1.0, 1.0),), 0.1)
