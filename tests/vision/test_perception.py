"""The pad detector on rendered frames: accuracy, lighting, blur, a partial pad, no pad."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from companion.config import PerceptionConfig
from companion.msg.pad import PadDetection
from companion.vision.perception import PadDetector, fit_circle
from sitl.camera import PAD_BGR, CameraRenderer
from sitl.config import CameraConfig, WorldConfig
from sitl.world import World


@pytest.fixture(scope="module")
def renderer() -> CameraRenderer:
    return CameraRenderer(CameraConfig(), World(WorldConfig()))


@pytest.fixture(scope="module")
def detector() -> PadDetector:
    return PadDetector(PerceptionConfig())


def view(renderer: CameraRenderer, dn: float, de: float, h: float, attitude=(0.0, 0.0, 0.0)):
    """(image, true centre, true equivalent radius) with the camera ``h`` above the pad."""
    pad = renderer.world.pad_ned(0.0)
    camera = pad + np.array([dn, de, -h])
    angles = np.linspace(0, 2 * math.pi, 120, endpoint=False)
    rim = pad + 0.5 * np.column_stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)])
    poly = renderer.project_many(rim, camera, attitude)[:, :2].astype(np.float32)
    radius = math.sqrt(cv2.contourArea(poly) / math.pi)
    return renderer.render(camera, attitude, 0.0), renderer.project(pad, camera, attitude), radius


def assert_close(found: PadDetection | None, centre, radius: float, centre_px: float, radius_rel: float,
                 partial: bool | None = None) -> None:
    """Found within ``centre_px`` of the centre and ``radius_rel`` of the radius (and, unless
    ``partial`` is None, found partial or whole as it says)."""
    assert found is not None, "pad not found"
    if partial is not None:
        assert found.partial == partial
    assert math.hypot(found.u_px - centre[0], found.v_px - centre[1]) <= centre_px
    assert abs(found.radius_px - radius) <= radius_rel * radius


@pytest.mark.parametrize(
    ("dn", "de", "h", "attitude"),
    [
        (0.0, 0.0, 8.0, (0.0, 0.0, 0.0)),
        (1.0, -0.5, 4.0, (0.1, -0.15, 1.0)),
        (-0.4, 0.6, 2.0, (-0.2, 0.2, -2.5)),
        (0.2, 0.1, 1.0, (0.05, 0.0, 0.3)),
    ],
)
def test_fully_visible_pad_is_found_to_a_pixel(renderer, detector, dn, de, h, attitude) -> None:
    image, centre, radius = view(renderer, dn, de, h, attitude)
    assert_close(detector.detect(image), centre, radius, centre_px=1.0, radius_rel=0.05, partial=False)


@pytest.mark.parametrize("gain", [0.35, 0.6, 1.5, 2.0])
def test_lighting_change(renderer, detector, gain: float) -> None:
    image, centre, radius = view(renderer, 0.8, 0.3, 5.0, (0.1, 0.05, 0.5))
    assert_close(detector.detect(cv2.convertScaleAbs(image, alpha=gain)), centre, radius, 1.0, 0.08)


def test_gamma_and_colour_cast(renderer, detector) -> None:
    image, centre, radius = view(renderer, -0.5, 0.5, 3.0)
    gamma = (255.0 * (image / 255.0) ** 1.8).astype(np.uint8)
    warm = np.clip(gamma.astype(int) * [0.85, 1.0, 1.15], 0, 255).astype(np.uint8)
    assert_close(detector.detect(warm), centre, radius, 1.0, 0.08)


@pytest.mark.parametrize("length_px", [5, 9])
def test_motion_blur(renderer, detector, length_px: int) -> None:
    image, centre, radius = view(renderer, 0.5, 0.5, 3.0, (0.0, 0.1, 0.8))
    kernel = np.zeros((length_px, length_px), np.float32)
    kernel[length_px // 2, :] = 1.0 / length_px  # horizontal, centred on the exposure's middle
    assert_close(detector.detect(cv2.filter2D(image, -1, kernel)), centre, radius, 1.5, 0.1)


def test_sensor_noise(renderer, detector, rng) -> None:
    image, centre, radius = view(renderer, -1.0, 0.7, 6.0, (0.15, -0.1, 2.0))
    noisy = np.clip(image + rng.normal(0.0, 10.0, image.shape), 0, 255).astype(np.uint8)
    assert_close(detector.detect(noisy), centre, radius, 1.0, 0.1)


def test_partial_pad_with_dot_in_view_keeps_the_centre(renderer, detector) -> None:
    # Pad 1.5 m west at 2 m: centre at u = 39.5, radius 40 px -> cut by the left border.
    image, centre, radius = view(renderer, 0.0, 1.5, 2.0)
    assert_close(detector.detect(image), centre, radius, centre_px=1.0, radius_rel=0.1, partial=True)


def test_partial_pad_centre_outside_the_image_comes_from_the_rim(renderer, detector) -> None:
    # Pad centre 10 px left of the image: the dot is out of view, the rim arc is not.
    image, centre, radius = view(renderer, 0.0, 2.125, 2.0)
    assert centre[0] < 0
    found = detector.detect(image)
    assert_close(found, centre, radius, centre_px=3.0, radius_rel=0.1, partial=True)
    assert found is not None and found.u_px < 0


def test_dot_cut_by_the_border_does_not_bend_the_rim_fit(renderer, detector) -> None:
    # Pad centre at u = 5 px: the dot (8 px) is cut by the border and its edge joins the outline.
    image, centre, radius = view(renderer, 0.0, 1.93, 2.0)
    assert_close(detector.detect(image), centre, radius, centre_px=2.0, radius_rel=0.05, partial=True)


@pytest.mark.parametrize(("dn", "de", "h"), [(6.0, 0.0, 3.0), (0.0, -9.0, 6.0), (-15.0, 12.0, 8.0), (30.0, 30.0, 1.0)])
def test_no_pad_in_view_gives_none(renderer, detector, dn, de, h) -> None:
    image, _, _ = view(renderer, dn, de, h, (0.1, -0.1, 0.3))
    assert detector.detect(image) is None


def test_random_noise_and_grey_give_none(detector, rng) -> None:
    assert detector.detect(rng.integers(0, 256, size=(240, 320, 3), dtype=np.uint8)) is None
    assert detector.detect(np.full((240, 320, 3), 128, np.uint8)) is None


def test_a_magenta_shape_that_is_not_convex_is_rejected(detector) -> None:
    image = np.full((240, 320, 3), 120, np.uint8)
    cv2.rectangle(image, (50, 50), (200, 60), PAD_BGR, -1)
    cv2.rectangle(image, (50, 50), (60, 200), PAD_BGR, -1)  # an L
    assert detector.detect(image) is None
    cv2.circle(image, (250, 150), 20, PAD_BGR, -1)  # a real disc beside it still wins
    found = detector.detect(image)
    assert found is not None and found.u_px == pytest.approx(250, abs=0.5)


def test_detector_refuses_non_bgr_input(detector) -> None:
    with pytest.raises(ValueError, match="BGR"):
        detector.detect(np.zeros((240, 320), np.uint8))


def test_fit_circle_recovers_an_arc() -> None:
    t = np.linspace(0.2, 1.8, 40)
    pts = np.column_stack([-10 + 50 * np.cos(t), 30 + 50 * np.sin(t)])
    cu, cv, r = fit_circle(pts)
    assert (cu, cv, r) == pytest.approx((-10, 30, 50), abs=1e-6)
    assert fit_circle(np.column_stack([np.arange(20.0), np.arange(20.0)])) is None


def test_pad_detection_validates_itself() -> None:
    with pytest.raises(ValueError):
        PadDetection(float("nan"), 1.0, 2.0, False)
    with pytest.raises(ValueError):
        PadDetection(1.0, 1.0, 0.0, False)
