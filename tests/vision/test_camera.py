"""The SITL camera: intrinsics, mounting, projection geometry and what the renderer draws."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sitl.camera import PAD_BGR, SKY_BGR, CameraRenderer, rotation_ned_from_body
from sitl.config import CameraConfig, WorldConfig
from sitl.world import World

HEIGHT_ABOVE_PAD_M = 4.0


@pytest.fixture(scope="module")
def renderer() -> CameraRenderer:
    return CameraRenderer(CameraConfig(), World(WorldConfig()))


def above_pad(renderer: CameraRenderer, dn: float = 0.0, de: float = 0.0, h: float = HEIGHT_ABOVE_PAD_M) -> np.ndarray:
    return renderer.world.pad_ned(0.0) + np.array([dn, de, -h])


def test_intrinsics_follow_the_field_of_view(renderer: CameraRenderer) -> None:
    assert renderer.fx == pytest.approx(160.0)  # 320 px, 90 degrees
    assert renderer.fy == renderer.fx
    assert (renderer.cx, renderer.cy) == (159.5, 119.5)
    assert renderer.vfov_rad == pytest.approx(2 * math.atan(120 / 160))


def test_rotation_is_a_proper_rotation() -> None:
    r = rotation_ned_from_body([0.3, -0.2, 2.0])
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(r) == pytest.approx(1.0)


def test_pad_straight_below_is_at_the_principal_point(renderer: CameraRenderer) -> None:
    uv = renderer.project(renderer.world.pad_ned(0.0), above_pad(renderer), [0, 0, 0])
    assert uv == pytest.approx((159.5, 119.5))


@pytest.mark.parametrize(
    ("dn", "de", "yaw", "expected"),
    [
        (1.0, 0.0, 0.0, (159.5, 119.5 + 40.0)),  # pad 1 m south of us: below the centre (top = north)
        (0.0, 1.0, 0.0, (159.5 - 40.0, 119.5)),  # pad 1 m west of us: left of the centre
        (-1.0, 0.0, math.pi / 2, (159.5 - 40.0, 119.5)),  # facing east, pad to the north = left
    ],
)
def test_horizontal_offsets_move_the_pad_as_documented(renderer, dn, de, yaw, expected) -> None:
    uv = renderer.project(renderer.world.pad_ned(0.0), above_pad(renderer, dn, de), [0, 0, yaw])
    assert uv == pytest.approx(expected)


def test_roll_right_moves_the_point_below_to_the_right(renderer: CameraRenderer) -> None:
    roll = math.radians(10)
    uv = renderer.project(renderer.world.pad_ned(0.0), above_pad(renderer), [roll, 0, 0])
    assert uv == pytest.approx((159.5 + 160 * math.tan(roll), 119.5))


def test_pitch_up_moves_the_point_below_down_the_image(renderer: CameraRenderer) -> None:
    pitch = math.radians(15)
    uv = renderer.project(renderer.world.pad_ned(0.0), above_pad(renderer), [0, pitch, 0])
    assert uv == pytest.approx((159.5, 119.5 + 160 * math.tan(pitch)))


def test_points_behind_the_camera_have_no_pixel(renderer: CameraRenderer) -> None:
    camera = above_pad(renderer)
    assert renderer.project(camera + [0, 0, -1.0], camera, [0, 0, 0]) is None


def test_project_many_agrees_with_project(renderer: CameraRenderer, rng) -> None:
    camera, attitude = above_pad(renderer, 0.5, -0.3), [0.1, -0.2, 1.0]
    points = rng.uniform(-3, 3, size=(5, 3)) * [1, 1, 0]
    uvd = renderer.project_many(points, camera, attitude)
    for p, row in zip(points, uvd, strict=True):
        assert renderer.project(p, camera, attitude) == pytest.approx(tuple(row[:2]))


def test_render_shape_dtype_and_determinism(renderer: CameraRenderer) -> None:
    camera, attitude = above_pad(renderer, 0.3, 0.2), [0.05, -0.1, 0.4]
    image = renderer.render(camera, attitude, 0.0)
    assert image.shape == (240, 320, 3) and image.dtype == np.uint8
    np.testing.assert_array_equal(image, renderer.render(camera, attitude, 0.0))


def test_pad_is_drawn_where_it_projects(renderer: CameraRenderer) -> None:
    camera, attitude = above_pad(renderer, 0.8, -0.6), [0.1, 0.05, 0.7]
    image = renderer.render(camera, attitude, 0.0)
    # A point on the magenta ring between the white dot (0.1 m) and the rim (0.5 m).
    ring_point = renderer.world.pad_ned(0.0) + [0.3, 0.0, 0.0]
    u, v = renderer.project(ring_point, camera, attitude)
    assert np.abs(image[round(v), round(u)].astype(int) - PAD_BGR).max() < 25


def test_moving_vehicle_carries_the_pad(rng) -> None:
    world = World(WorldConfig(vehicle_velocity_ne_m_s=(2.0, 1.0)))
    renderer = CameraRenderer(CameraConfig(), world)
    t_s = 3.0
    camera = world.pad_ned(t_s) + [0.0, 0.0, -5.0]
    image = renderer.render(camera, [0, 0, 0], t_s)
    u, v = renderer.project(world.pad_ned(t_s) + [0.0, 0.3, 0.0], camera, [0, 0, 0])
    assert np.abs(image[round(v), round(u)].astype(int) - PAD_BGR).max() < 25
    # Where the pad was at t = 0 is now ground, not pad.
    old = renderer.project(world.pad_ned(0.0) + [0.0, 0.3, 0.0], camera, [0, 0, 0])
    if old is not None and 0 <= old[0] < 320 and 0 <= old[1] < 240:
        assert np.abs(image[round(old[1]), round(old[0])].astype(int) - PAD_BGR).max() > 60


def test_ground_is_textured_and_seeded(renderer: CameraRenderer) -> None:
    camera = above_pad(renderer, 30.0, 30.0, 5.0)  # far from the vehicle: ground only
    image = renderer.render(camera, [0, 0, 0], 0.0)
    assert image.std() > 5.0
    other = CameraRenderer(CameraConfig(texture_seed=1), renderer.world).render(camera, [0, 0, 0], 0.0)
    assert np.abs(image.astype(int) - other).mean() > 5.0


def test_horizon_shows_sky_above_it(renderer: CameraRenderer) -> None:
    image = renderer.render(above_pad(renderer, h=3.0), [0.0, 1.3, 0.0], 0.0)
    assert np.abs(image[2, 160].astype(int) - SKY_BGR).max() < 3
    assert np.abs(image[-2, 160].astype(int) - SKY_BGR).max() > 30


def test_camera_on_or_under_the_ground_still_renders(renderer: CameraRenderer) -> None:
    landed = renderer.render([20.0, 0.0, 0.0], [0, 0, 0], 0.0)
    np.testing.assert_array_equal(landed, renderer.render([20.0, 0.0, 0.01], [0, 0, 0], 0.0))
    assert landed.std() > 0.5


def test_render_refuses_a_non_finite_pose(renderer: CameraRenderer) -> None:
    with pytest.raises(ValueError, match="finite"):
        renderer.render([0.0, float("nan"), -3.0], [0, 0, 0], 0.0)
    with pytest.raises(ValueError, match="finite"):
        renderer.render([0.0, 0.0, -3.0], [0, float("inf"), 0], 0.0)
