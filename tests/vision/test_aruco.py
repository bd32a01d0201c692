"""The ArUco pad detector on rendered images: the pose it gives against the pose rendered."""

from __future__ import annotations

import numpy as np
import pytest

from companion.vision.aruco import ArucoPadDetector, PadPose
from companion.vision.perception import PadDetector
from sitl import pad_marker
from sitl.camera import CAM_FROM_BODY, CameraRenderer, camera_matrix, rotation_ned_from_body
from sitl.config import CameraConfig, WorldConfig
from sitl.world import World

MARKED = CameraConfig(pad_marker="aruco")
IN_DISC = CameraConfig(pad_marker="aruco-disc")


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


@pytest.fixture(scope="module")
def disc_renderer() -> CameraRenderer:
    return CameraRenderer(IN_DISC, World(WorldConfig()))


@pytest.fixture(scope="module")
def disc_detector() -> ArucoPadDetector:
    return ArucoPadDetector(camera_matrix(IN_DISC), (IN_DISC.width_px, IN_DISC.height_px), board="aruco-disc")


@pytest.mark.parametrize("board", pad_marker.BOARDS)
def test_each_board_fits_the_default_roof_and_its_markers_do_not_overlap(board: str) -> None:
    world, camera = WorldConfig(), CameraConfig()
    pad_marker.check_fits(board, world.vehicle_length_m, world.vehicle_width_m, world.pad_radius_m, camera.pad_dot_radius_m)
    boxes = [(m.north_m - m.size_m, m.north_m, m.east_m, m.east_m + m.size_m) for m in pad_marker.markers(board)]
    for i, a in enumerate(boxes):
        for b in boxes[i + 1:]:
            apart = a[1] <= b[0] or b[1] <= a[0] or a[3] <= b[2] or b[3] <= a[2]
            assert apart, (a, b)
    with pytest.raises(ValueError, match="vehicle_width_m"):
        pad_marker.check_fits(board, 4.0, 0.9, world.pad_radius_m, camera.pad_dot_radius_m)


def test_the_boards_share_no_marker_id_so_the_wrong_board_reads_nothing(
        disc_renderer: CameraRenderer, detector: ArucoPadDetector) -> None:
    ids = [{m.marker_id for m in pad_marker.markers(board)} for board in pad_marker.BOARDS]
    assert not set.intersection(*ids)
    image = disc_renderer.render(disc_renderer.world.pad_ned(0.0) + np.array([0.0, 0.0, -2.0]), (0.0, 0.0, 0.0), 0.0)
    assert detector.detect(image) is None  # the aruco board's detector on the aruco-disc pad


@pytest.mark.parametrize(("pad_radius_m", "dot_radius_m", "problem"), [
    (0.5, 0.07, "pad_dot_radius_m >= 0.094"),  # the centre marker leaves the dot
    (0.45, 0.1, "pad_radius_m >= 0.484"),  # the ring reaches the rim
    (0.5, 0.13, "pad_dot_radius_m <= 0.120"),  # the dot reaches the ring
    (0.6, 0.1, "would cover the disc"),  # the roof markers' white squares on the disc
])
def test_the_board_in_the_disc_refuses_a_pad_it_does_not_fit(pad_radius_m: float, dot_radius_m: float, problem: str) -> None:
    with pytest.raises(ValueError, match=problem):
        pad_marker.check_fits("aruco-disc", 4.0, 2.0, pad_radius_m, dot_radius_m)
    with pytest.raises(ValueError, match="no ArUco board 'qr'"):
        pad_marker.markers("qr")


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


@pytest.mark.parametrize(("board", "height_m", "ids"), [
    ("aruco", 0.15, {0}), ("aruco", 0.6, {0}), ("aruco", 5.0, {1, 2, 3, 4}), ("aruco", 8.0, {5, 6}),
    ("aruco-disc", 0.15, {7}), ("aruco-disc", 0.6, {7}), ("aruco-disc", 1.6, {8, 9, 10, 11}), ("aruco-disc", 8.0, {12, 13}),
])
def test_each_board_is_read_from_the_start_height_down_to_touchdown(
        request: pytest.FixtureRequest, board: str, height_m: float, ids: set[int]) -> None:
    """The centre marker near touchdown, the ring in between, the outer pair from the start."""
    prefix = "" if board == "aruco" else "disc_"
    renderer, detector = request.getfixturevalue(f"{prefix}renderer"), request.getfixturevalue(f"{prefix}detector")
    pose, t, _ = pose_at(renderer, detector, height_m, (0.0, 0.0), (0.0, 0.0, 0.0))
    assert pose is not None
    assert ids <= set(pose.marker_ids)
    assert np.linalg.norm(np.array(pose.position_cam_m) - t) < 0.02 * height_m + 0.02


def test_the_colour_detector_sees_the_plain_pad_through_the_board_in_the_disc_and_not_through_the_other(
        renderer: CameraRenderer, disc_renderer: CameraRenderer) -> None:
    """What the learned policies observe: the same detection, to a fraction of a pixel, with the
    board inked into the pad as without it (20 poses from 0.3 m to 9 m, tilted, any yaw); the
    board over the pad hides it."""
    plain = CameraRenderer(CameraConfig(), disc_renderer.world)
    colour = PadDetector()
    rng = np.random.default_rng(3)
    pad = plain.world.pad_ned(0.0)
    found = 0
    for height in np.geomspace(0.3, 9.0, 20):
        offset = rng.uniform(-0.3, 0.3, 2) * height
        position = pad + np.array([offset[0], offset[1], -height])
        attitude = (*rng.uniform(-0.25, 0.25, 2), rng.uniform(-np.pi, np.pi))
        seen = colour.detect(plain.render(position, attitude, 0.0))
        inked = colour.detect(disc_renderer.render(position, attitude, 0.0))
        assert (seen is None) == (inked is None), (height, seen, inked)
        if seen is None:
            continue
        found += 1
        assert abs(inked.u_px - seen.u_px) < 0.5 and abs(inked.v_px - seen.v_px) < 0.5, (height, seen, inked)
        assert abs(inked.radius_px - seen.radius_px) < 0.25, (height, seen, inked)
        assert inked.partial == seen.partial
        if height > 1.0:  # from lower the old board's white square fills the view
            assert colour.detect(renderer.render(position, attitude, 0.0)) is None, height
    assert found >= 18


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
