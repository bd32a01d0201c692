"""LANDING_TARGET's content against the detector's output (issue 27's done-when)."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from companion.link.landing_target import (
    LANDING_TARGET_TYPE_VISION_FIDUCIAL,
    MAV_FRAME_BODY_FRD,
    MAV_FRAME_LOCAL_NED,
    LandingTarget,
    landing_target,
    quaternion,
)
from companion.vision.aruco import ArucoPadDetector, PadPose
from sitl.camera import CAM_FROM_BODY, CameraRenderer, camera_matrix, rotation_ned_from_body
from sitl.config import CameraConfig, WorldConfig
from sitl.world import World

MARKED = CameraConfig(pad_marker="aruco")
K = camera_matrix(MARKED)
VEHICLE_NED = np.array([0.4, -0.3, -4.0])  # 2.5 m above the roof's pad
ATTITUDE = (0.06, -0.04, 0.7)


@pytest.fixture(scope="module")
def seen() -> tuple[PadPose, np.ndarray]:
    """The detector's pose of the pad from VEHICLE_NED, and the pad's true NED position."""
    renderer = CameraRenderer(MARKED, World(WorldConfig()))
    image = renderer.render(VEHICLE_NED, ATTITUDE, 0.0)
    pose = ArucoPadDetector(K, (MARKED.width_px, MARKED.height_px)).detect(image)
    assert pose is not None
    return pose, renderer.world.pad_ned(0.0)


def rotation_of(q: tuple[float, float, float, float]) -> np.ndarray:
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def test_angles_distance_and_size_are_the_detections(seen: tuple[PadPose, np.ndarray]) -> None:
    pose, _ = seen
    tx, ty, tz = pose.position_cam_m
    target = landing_target(pose, K, 12_345, MAV_FRAME_BODY_FRD)
    assert target.angle_x == pytest.approx(math.atan(tx / tz))
    assert target.angle_y == pytest.approx(math.atan(ty / tz))
    assert target.distance == pytest.approx(math.sqrt(tx * tx + ty * ty + tz * tz))
    u = np.array([c[0] for c in pose.corners_px])
    v = np.array([c[1] for c in pose.corners_px])
    assert target.size_x == pytest.approx(math.atan((u.max() - K[0, 2]) / K[0, 0]) - math.atan((u.min() - K[0, 2]) / K[0, 0]))
    assert target.size_y == pytest.approx(math.atan((v.max() - K[1, 2]) / K[1, 1]) - math.atan((v.min() - K[1, 2]) / K[1, 1]))
    assert 0 < target.size_x < math.radians(90) and 0 < target.size_y < math.radians(90)
    assert (target.time_usec, target.target_num, target.type, target.position_valid) == (
        12_345_000, 0, LANDING_TARGET_TYPE_VISION_FIDUCIAL, 1)


def test_body_frd_is_the_camera_position_in_body_axes_and_agrees_with_the_angles(
        seen: tuple[PadPose, np.ndarray]) -> None:
    """ArduPilot reads x, y, z / distance as its line of sight, and the angle form as
    (-tan angle_y, tan angle_x, 1): both must point the same way."""
    pose, pad = seen
    target = landing_target(pose, K, 0, MAV_FRAME_BODY_FRD)
    body = CAM_FROM_BODY.T @ np.array(pose.position_cam_m)
    np.testing.assert_allclose([target.x, target.y, target.z], body, atol=1e-9)
    los = np.array([target.x, target.y, target.z]) / target.distance
    from_angles = np.array([-math.tan(target.angle_y), math.tan(target.angle_x), 1.0])
    np.testing.assert_allclose(los, from_angles / np.linalg.norm(from_angles), atol=1e-9)
    true_body = rotation_ned_from_body(ATTITUDE).T @ (pad - VEHICLE_NED)
    assert np.linalg.norm(body - true_body) < 0.05
    # the pad frame (north, east, down) in body axes: the vehicle's attitude, inverted
    r = rotation_of(target.q)
    angle = math.degrees(math.acos(np.clip((np.trace(r.T @ rotation_ned_from_body(ATTITUDE).T) - 1) / 2, -1, 1)))
    assert angle < 3.0


def test_local_ned_is_the_pads_position_in_the_vehicles_frame(seen: tuple[PadPose, np.ndarray]) -> None:
    """PX4 reads x, y, z as the target's position in its local frame (landing_target_pose x_abs)."""
    pose, pad = seen
    target = landing_target(pose, K, 0, MAV_FRAME_LOCAL_NED, ATTITUDE, VEHICLE_NED)
    assert target.frame == MAV_FRAME_LOCAL_NED
    assert np.linalg.norm(np.array([target.x, target.y, target.z]) - pad) < 0.05
    r = rotation_of(target.q)  # the pad is level and north-aligned
    assert math.degrees(math.acos(np.clip((np.trace(r) - 1) / 2, -1, 1))) < 3.0
    # the same pose from another vehicle position moves x, y, z by exactly that much
    moved = landing_target(pose, K, 0, MAV_FRAME_LOCAL_NED, ATTITUDE, VEHICLE_NED + np.array([1.0, 2.0, 0.5]))
    np.testing.assert_allclose([moved.x - target.x, moved.y - target.y, moved.z - target.z], [1.0, 2.0, 0.5])


def test_it_survives_pymavlinks_wire_format(seen: tuple[PadPose, np.ndarray]) -> None:
    pose, _ = seen
    target = landing_target(pose, K, 987_654, MAV_FRAME_LOCAL_NED, ATTITUDE, VEHICLE_NED)
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=191)
    buf = mav.landing_target_encode(*target.encode_args()).pack(mav)
    msg = mavlink.MAVLink(None).parse_char(buf)
    assert msg.get_type() == "LANDING_TARGET"
    assert (msg.time_usec, msg.frame, msg.type, msg.position_valid) == (987_654_000, 1, 2, 1)
    for name in ("angle_x", "angle_y", "distance", "size_x", "size_y", "x", "y", "z"):
        assert getattr(msg, name) == pytest.approx(getattr(target, name), rel=1e-6, abs=1e-6)
    np.testing.assert_allclose(msg.q, target.q, atol=1e-6)


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -float("inf")])
def test_non_finite_values_are_refused(seen: tuple[PadPose, np.ndarray], bad: float) -> None:
    pose, _ = seen
    with pytest.raises(ValueError, match="finite"):
        landing_target(pose, K, 0, MAV_FRAME_LOCAL_NED, (0.0, bad, 0.0), VEHICLE_NED)
    with pytest.raises(ValueError, match="finite"):
        landing_target(pose, K, 0, MAV_FRAME_LOCAL_NED, ATTITUDE, (bad, 0.0, 0.0))
    good = landing_target(pose, K, 0, MAV_FRAME_BODY_FRD)
    fields = good.__dict__ | {"x": bad}
    with pytest.raises(ValueError, match="finite"):
        LandingTarget(**fields)


def test_frames_an_autopilot_would_refuse_are_refused(seen: tuple[PadPose, np.ndarray]) -> None:
    pose, _ = seen
    with pytest.raises(ValueError, match="MAV_FRAME"):
        landing_target(pose, K, 0, 8)
    good = landing_target(pose, K, 0, MAV_FRAME_BODY_FRD)
    with pytest.raises(ValueError, match="distance"):
        LandingTarget(**(good.__dict__ | {"distance": 0.0}))
    with pytest.raises(ValueError, match="unit quaternion"):
        LandingTarget(**(good.__dict__ | {"q": (0.0, 0.0, 0.0, 0.0)}))


@pytest.mark.parametrize("seed", range(5))
def test_quaternion_matches_the_rotation(seed: int) -> None:
    rng = np.random.default_rng(seed)
    rotation, _ = cv2.Rodrigues(rng.uniform(-3.0, 3.0, 3))
    q = quaternion(rotation)
    assert q[0] >= 0
    np.testing.assert_allclose(rotation_of(q), rotation, atol=1e-9)
    assert quaternion(np.diag([1.0, -1.0, -1.0])) == pytest.approx((0.0, 1.0, 0.0, 0.0))
