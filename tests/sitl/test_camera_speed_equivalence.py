"""The optimised camera renderer and pad detector against their frozen pre-optimisation copies
(tests/sitl/camera_reference.py): the same frames, bit for bit, and the same detections, float for
float, over hundreds of random poses and images.

The poses cover what each shortcut depends on: the pad fully in view, cut by the border and out of
view; tilted views up to the horizon (sky); views whose ground samples stay inside one repeat of the
tile (BORDER_CONSTANT) or cross it (BORDER_WRAP); the vehicle's silhouette filling the whole frame
(ground and sky skipped); a camera on the ground; a moving ground vehicle; the disturbances at levels
above 0 (camera misalignment, pixel noise); and other camera settings. Each test also checks that
every shortcut was taken often enough for the comparison to mean something.
"""

from __future__ import annotations

import math
from collections import Counter
from unittest import mock

import cv2
import numpy as np
import pytest

import sitl.camera as camera_module
from companion.config import PerceptionConfig
from companion.vision import perception as perception_module
from companion.vision.perception import PadDetector
from sitl.camera import CameraRenderer
from sitl.config import CameraConfig, DisturbanceConfig, WorldConfig
from sitl.disturbance import EpisodeDisturbance
from sitl.world import World
from tests.sitl.camera_reference import ReferenceDetector, ReferenceRenderer

MAX_TILT_RAD = math.radians(20.0)


def _pose_around_pad(rng: np.random.Generator, pad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """As bench/perception.py: 0.3-8 m above the pad, tilt up to 20 degrees, any yaw, an offset
    that puts the pad fully in view, cut by the border or out of view."""
    height = rng.uniform(0.3, 8.0)
    reach = 1.1 * height + 0.5
    position = pad + np.array([*rng.uniform(-reach, reach, size=2), -height])
    attitude = np.array([*rng.uniform(-MAX_TILT_RAD, MAX_TILT_RAD, size=2), rng.uniform(-math.pi, math.pi)])
    return position, attitude


def _pose(rng: np.random.Generator, pad: np.ndarray, kind: int) -> tuple[np.ndarray, np.ndarray]:
    if kind == 0:  # around the pad
        return _pose_around_pad(rng, pad)
    if kind == 1:  # low over the roof: the silhouette and the level-0 roof fill the frame
        position = pad + np.array([rng.uniform(-1.8, 1.8), rng.uniform(-0.9, 0.9), -rng.uniform(0.01, 1.0)])
        return position, np.array([*rng.normal(0.0, 0.08, size=2), rng.uniform(-math.pi, math.pi)])
    if kind == 2:  # far, high, tilted up to near the horizon or beyond: sky, wrapped ground
        position = np.array([*rng.uniform(-40.0, 40.0, size=2), -rng.uniform(0.0, 30.0)])
        return position, np.array([*rng.uniform(-1.5, 1.5, size=2), rng.uniform(-math.pi, math.pi)])
    # on, or numerically under, the ground, anywhere near the vehicle
    position = pad + np.array([*rng.uniform(-6.0, 6.0, size=2), 1.5 + rng.uniform(-0.05, 0.3)])
    return position, np.array([*rng.uniform(-0.4, 0.4, size=2), rng.uniform(-math.pi, math.pi)])


def _disturbance(rng: np.random.Generator) -> EpisodeDisturbance | None:
    if rng.random() < 0.4:
        return None
    level = float(rng.choice([0.2, 0.5, 1.0]))
    return EpisodeDisturbance.draw(DisturbanceConfig(level=level), int(rng.integers(0, 10_000)))


class _Counting:
    """Counts which branch each renderer shortcut took (wraps, so behaviour is unchanged)."""

    def __init__(self) -> None:
        self.counts: Counter[str] = Counter()
        inside, covers = camera_module._samples_inside, CameraRenderer._covers_image

        def samples_inside(*args):
            out = inside(*args)
            self.counts["ground BORDER_CONSTANT" if out else "ground BORDER_WRAP"] += 1
            return out

        def covers_image(renderer, outline):
            out = covers(renderer, outline)
            self.counts["silhouette fills the frame"] += out
            return out

        self.patches = [
            mock.patch.object(camera_module, "_samples_inside", samples_inside),
            mock.patch.object(CameraRenderer, "_covers_image", covers_image),
        ]

    def __enter__(self) -> Counter[str]:
        for p in self.patches:
            p.start()
        return self.counts

    def __exit__(self, *exc) -> None:
        for p in self.patches:
            p.stop()


def _render_both(new: CameraRenderer, ref: ReferenceRenderer, pose, t_s: float, dist: EpisodeDisturbance | None,
                 step: int) -> tuple[np.ndarray, np.ndarray]:
    position, attitude = pose
    mount = dist.camera_mount if dist is not None else None
    a, b = new.render(position, attitude, t_s, mount), ref.render(position, attitude, t_s, mount)
    if dist is not None:  # what sitl.camera_feed.render_frame sends
        a, b = dist.add_image_noise(a, step), dist.add_image_noise(b, step)
    return a, b


@pytest.mark.parametrize(
    ("camera", "poses"),
    [
        (CameraConfig(), 600),
        (CameraConfig(ground_downsample=1), 80),
        (CameraConfig(ground_downsample=3), 80),
        (CameraConfig(width_px=160, height_px=120, hfov_deg=70.0, ground_downsample=4, texture_seed=3), 80),
    ],
    ids=["default", "downsample1", "downsample3", "small-narrow-ds4"],
)
def test_rendered_frames_are_bit_identical_to_the_reference(camera: CameraConfig, poses: int) -> None:
    rng = np.random.default_rng(20240611 + camera.ground_downsample)
    world = World(WorldConfig())
    new, ref = CameraRenderer(camera, world), ReferenceRenderer(camera, world)
    pad = world.pad_ned(0.0)
    differing = []
    with _Counting() as counts:
        for i in range(poses):
            if i % 7 == 6:  # the ground vehicle drives: the same world time for both
                world.restart(0.0, tuple(rng.uniform(-0.5, 0.5, size=2)))
                t_s = float(rng.uniform(0.0, 4.0))
                pad_now = world.pad_ned(t_s)
            else:
                world.restart(0.0)
                t_s, pad_now = 0.0, pad
            pose = _pose(rng, pad_now, i % 4)
            a, b = _render_both(new, ref, pose, t_s, _disturbance(rng), i)
            assert a.shape == b.shape and a.dtype == b.dtype
            if not np.array_equal(a, b):
                differing.append((i, int(np.count_nonzero((a != b).any(axis=2)))))
    assert not differing, f"frames differing (pose index, pixels): {differing[:10]}"
    # every path was taken
    assert counts["ground BORDER_CONSTANT"] >= poses // 20, counts
    assert counts["ground BORDER_WRAP"] >= poses // 20, counts
    assert counts["silhouette fills the frame"] >= poses // 40, counts


def test_a_camera_looking_at_the_sky_and_a_camera_inside_the_box_stay_identical() -> None:
    world = World(WorldConfig())
    new, ref = CameraRenderer(CameraConfig(), world), ReferenceRenderer(CameraConfig(), world)
    pad = world.pad_ned(0.0)
    cases = [
        (pad + np.array([0.0, 0.0, -0.3]), np.zeros(3)),  # touchdown
        (pad + np.array([0.0, 0.0, 0.5]), np.zeros(3)),  # inside the box, below its roof
        (np.array([30.0, 0.0, -2.0]), np.array([0.0, 1.45, 0.0])),  # pitched up to the horizon
        (np.array([0.0, 0.0, -5.0]), np.array([math.pi, 0.0, 0.0])),  # upside down: all sky
        (pad + np.array([1.9, 0.9, -0.05]), np.array([0.0, 0.0, 0.3])),  # over a roof corner
        (np.array([0.0, 0.0, 0.0]), np.zeros(3)),  # on the ground
    ]
    for position, attitude in cases:
        assert np.array_equal(new.render(position, attitude, 0.0), ref.render(position, attitude, 0.0))


def _perturbed(image: np.ndarray, rng: np.random.Generator, k: int) -> np.ndarray:
    """Lighting, motion blur, gamma and colour cast, sensor noise, JPEG: images the renderer never
    makes, for the detector."""
    kind = k % 6
    if kind == 0:
        return image
    if kind == 1:
        return cv2.convertScaleAbs(image, alpha=float(rng.uniform(0.3, 2.0)))
    if kind == 2:
        length = int(rng.integers(3, 10))
        kernel = np.zeros((length, length), np.float32)
        kernel[length // 2, :] = 1.0 / length
        return cv2.filter2D(image, -1, kernel)
    if kind == 3:
        gamma = (255.0 * (image / 255.0) ** rng.uniform(0.5, 2.0)).astype(np.uint8)
        return np.clip(gamma.astype(int) * rng.uniform(0.8, 1.2, size=3), 0, 255).astype(np.uint8)
    if kind == 4:
        return np.clip(image + rng.normal(0.0, rng.uniform(2.0, 25.0), image.shape), 0, 255).astype(np.uint8)
    ok, jpeg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, int(rng.integers(30, 95))])
    assert ok
    return cv2.imdecode(jpeg, cv2.IMREAD_COLOR)


def _fields(found) -> tuple | None:
    return None if found is None else (found.u_px, found.v_px, found.radius_px, found.partial)


@pytest.mark.parametrize(
    "perception",
    [PerceptionConfig(), PerceptionConfig(hue_min=140, hue_max=165, saturation_min=80, value_min=60)],
    ids=["default", "other-thresholds"],
)
def test_detections_are_identical_to_the_reference(perception: PerceptionConfig) -> None:
    rng = np.random.default_rng(7)
    world = World(WorldConfig())
    renderer = CameraRenderer(CameraConfig(), world)
    new, ref = PadDetector(perception), ReferenceDetector(perception)
    pad = world.pad_ned(0.0)
    outcomes: Counter[str] = Counter()
    images = 720
    for k in range(images):
        pose = _pose(rng, pad, 0 if k % 3 else int(rng.integers(0, 4)))
        dist = _disturbance(rng)
        image = renderer.render(*pose, 0.0, dist.camera_mount if dist is not None else None)
        if dist is not None:
            image = dist.add_image_noise(image, k)
        image = _perturbed(image, rng, k)
        if k % 90 == 89:
            image = rng.integers(0, 256, size=image.shape, dtype=np.uint8)
        a, b = _fields(new.detect(image)), _fields(ref.detect(image))
        assert a == b, f"image {k}: {a} != {b}"
        assert np.array_equal(new.mask(image), ref.mask(image)), f"image {k}"
        outcomes["none" if a is None else "partial" if a[3] else "full"] += 1
    assert outcomes["full"] >= images // 10 and outcomes["partial"] >= images // 20 and outcomes["none"] >= images // 10, outcomes


@pytest.mark.parametrize(
    "perception",
    [PerceptionConfig(), PerceptionConfig(hue_min=125, hue_max=175, saturation_min=60, value_min=20)],
    ids=["default", "wider"],
)
def test_masks_are_identical_for_every_colour(perception: PerceptionConfig) -> None:
    """All 2^24 colours through both detectors' masks (64 images of 256 x 1024); and the pre-test's
    margin holds for every colour the reference accepts: min(B, R) - G >= margin."""
    new, ref = PadDetector(perception), ReferenceDetector(perception)
    margin = perception_module._green_margin(new._lo.tobytes(), new._hi.tobytes())
    assert margin is not None and margin >= 1
    levels = np.arange(256, dtype=np.uint8)
    image = np.empty((256, 1024, 3), np.uint8)
    image[..., 0] = np.tile(levels, 4)[None, :]  # blue along the row
    image[..., 2] = levels[:, None]  # red down the column
    accepted = 0
    for g0 in range(0, 256, 4):
        image[..., 1] = np.repeat(np.arange(g0, g0 + 4, dtype=np.uint8), 256)[None, :]  # 4 greens per image
        expected = ref.mask(image)
        assert np.array_equal(new.mask(image), expected), f"greens {g0}..{g0 + 3}"
        px = image[expected > 0].astype(int)
        accepted += len(px)
        if len(px):
            assert (np.minimum(px[:, 0], px[:, 2]) - px[:, 1]).min() >= margin
    assert accepted > 100_000


def test_layouts_the_fast_path_does_not_take_and_thresholds_without_a_pre_test() -> None:
    new, ref = PadDetector(), ReferenceDetector()
    rng = np.random.default_rng(3)
    renderer = CameraRenderer(CameraConfig(), World(WorldConfig()))
    frame = renderer.render(renderer.world.pad_ned(0.0) + np.array([0.4, -0.2, -2.5]), (0.1, 0.0, 0.5), 0.0)
    noisy = np.clip(frame + rng.normal(0.0, 3.0, frame.shape), 0, 255).astype(np.uint8)
    # non-contiguous views, an odd height, a height that is not a multiple of 4
    for image in (frame[:, ::-1], noisy[7:230, 3:300], frame[1:], np.ascontiguousarray(noisy[:-1]),
                  np.ascontiguousarray(frame[:-2])):
        assert np.array_equal(new.mask(image), ref.mask(image))
        assert _fields(new.detect(image)) == _fields(ref.detect(image))
    # a hue range where green can be the largest channel: no pre-test, the same mask all the same
    green_hues = PerceptionConfig(hue_min=40, hue_max=80)
    assert perception_module._green_margin(np.array([40, 110, 35], np.uint8).tobytes(),
                                           np.array([80, 255, 255], np.uint8).tobytes()) is None
    image = rng.integers(0, 256, size=(240, 320, 3), dtype=np.uint8)
    assert np.array_equal(PadDetector(green_hues).mask(image), ReferenceDetector(green_hues).mask(image))
