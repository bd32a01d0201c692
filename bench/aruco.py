"""Benchmark: the ArUco pad detector (companion/vision/aruco.py) on rendered frames.

Random poses over the pad as in bench/perception.py (height from touchdown to beyond the start,
roll and pitch up to 20 degrees, any yaw, an offset that keeps the pad's centre in view), truth
from the renderer's own pose. Per height band: how often the board is decoded, and the pose
error (metres, the pad centre in the camera frame) at the median and p95. Beside it, what the
colour detector the learned policies see through (companion/vision/perception.py) makes of the
same frame with the board against the plain pad: how often it finds the pad where it finds the
plain one, and how far its centre and radius move (pixels, median and p95). The last line of
stdout is one JSON object.

    python bench/aruco.py [--board aruco|aruco-disc] [--frames N] [--seed S]
"""

from __future__ import annotations

import argparse
import json
import math
import time

import cv2
import numpy as np
from machine_ref import machine_ref_rt

from companion.vision.aruco import ArucoPadDetector
from companion.vision.perception import PadDetector
from sitl.camera import CAM_FROM_BODY, CameraRenderer, camera_matrix, rotation_ned_from_body
from sitl.config import CameraConfig, WorldConfig
from sitl.world import World

BANDS_M = ((0.15, 1.0), (1.0, 3.0), (3.0, 6.0), (6.0, 8.0), (8.0, 10.0))
MAX_TILT_RAD = math.radians(20.0)


def sample(rng: np.random.Generator, renderer: CameraRenderer, pad: np.ndarray, low: float, high: float):  # type: ignore[no-untyped-def]
    """A pose whose image holds the pad's centre at least 10 % inside the border."""
    while True:
        height = rng.uniform(low, high)
        offset = rng.uniform(-0.8 * height, 0.8 * height, 2)
        position = pad + np.array([offset[0], offset[1], -height])
        attitude = (rng.uniform(-MAX_TILT_RAD, MAX_TILT_RAD), rng.uniform(-MAX_TILT_RAD, MAX_TILT_RAD), rng.uniform(-math.pi, math.pi))
        uv = renderer.project(pad, position, attitude)
        if uv is not None and 32 <= uv[0] <= 288 and 24 <= uv[1] <= 216:
            return position, attitude


class ColourShift:
    """The colour detector on the board against the plain pad, frame by frame."""

    def __init__(self) -> None:
        self.plain_found = self.both_found = 0
        self.centre_px: list[float] = []
        self.radius_px: list[float] = []

    def add(self, plain, marked) -> None:  # type: ignore[no-untyped-def]
        if plain is None:
            return
        self.plain_found += 1
        if marked is None:
            return
        self.both_found += 1
        self.centre_px.append(math.hypot(marked.u_px - plain.u_px, marked.v_px - plain.v_px))
        self.radius_px.append(abs(marked.radius_px - plain.radius_px))

    def summary(self) -> dict[str, object]:
        def pct(values: list[float], q: float) -> float | None:
            return round(float(np.percentile(values, q)), 3) if values else None
        return {"found_where_plain_found": round(self.both_found / max(self.plain_found, 1), 3),
                "centre_px_p50": pct(self.centre_px, 50), "centre_px_p95": pct(self.centre_px, 95),
                "radius_px_p50": pct(self.radius_px, 50), "radius_px_p95": pct(self.radius_px, 95)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--frames", type=int, default=100, help="frames per height band")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--board", choices=("aruco", "aruco-disc"), default="aruco", help="[sitl.camera] pad_marker")
    args = parser.parse_args()
    cv2.setNumThreads(1)
    cfg = CameraConfig(pad_marker=args.board)
    world = World(WorldConfig())
    renderer = CameraRenderer(cfg, world)
    plain = CameraRenderer(CameraConfig(), world)
    detector = ArucoPadDetector(camera_matrix(cfg), (cfg.width_px, cfg.height_px), board=args.board)
    colour = PadDetector()
    pad = renderer.world.pad_ned(0.0)
    rng = np.random.default_rng(args.seed)
    bands, times = [], []
    for low, high in BANDS_M:
        errors, seen, shifts = [], 0, ColourShift()
        for _ in range(args.frames):
            position, attitude = sample(rng, renderer, pad, low, high)
            image = renderer.render(position, attitude, 0.0)
            shifts.add(colour.detect(plain.render(position, attitude, 0.0)), colour.detect(image))
            start = time.perf_counter()
            pose = detector.detect(image)
            times.append(time.perf_counter() - start)
            if pose is None:
                continue
            seen += 1
            truth = CAM_FROM_BODY @ rotation_ned_from_body(attitude).T @ (pad - position)
            errors.append(float(np.linalg.norm(np.array(pose.position_cam_m) - truth)))
        p50 = round(float(np.median(errors)), 4) if errors else None  # None: nothing decoded (JSON has no NaN)
        p95 = round(float(np.percentile(errors, 95)), 4) if errors else None
        bands.append({"height_m": [low, high], "frames": args.frames, "decoded": round(seen / args.frames, 3),
                      "error_m_p50": p50, "error_m_p95": p95, "colour_vs_plain": shifts.summary()})
        print(f"{low:4.1f}-{high:4.1f} m: decoded {seen}/{args.frames}, error p50 {bands[-1]['error_m_p50']} m, "
              f"p95 {bands[-1]['error_m_p95']} m; colour detector vs the plain pad {shifts.summary()}")
    print(json.dumps({"bench": "aruco", "board": args.board, "seed": args.seed, "bands": bands,
                      "detect_ms_p50": round(float(np.median(times)) * 1e3, 2),
                      "machine_ref_rt": round(machine_ref_rt(), 1)}))


if __name__ == "__main__":
    main()
