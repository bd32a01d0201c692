"""Benchmark: the pad detector on rendered frames against the ground-truth projection.

Random poses: height above the pad from touchdown to the episode start height, roll and pitch
up to 20 degrees, any yaw, and a horizontal offset wide enough that the pad is sometimes fully in
view, sometimes cut by the border and sometimes out of view. Truth comes from projecting the
pad's centre and rim with the renderer's own camera model; the truth radius is the radius of a
circle with the projected rim's area.

Metrics: centre and radius errors and misses over frames with the pad fully in view; false
positives over frames with the pad out of view; median render and detect times. The machine may
be shared with other jobs, so times vary between runs. The last line of stdout is one JSON object.

    python bench/perception.py [--quick] [--frames N] [--seed S] [--lighting] [--blur] [--noise] [--jpeg]
                               [--cv-threads N]

OpenCV runs on one thread by default, as in the experiment (``--cv-threads 0``: OpenCV's own
default). Besides the wall-clock medians, ``*_cpu_ms_p50`` are medians of this thread's CPU time,
which a busy machine disturbs less.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time

import cv2
import numpy as np
from machine_ref import machine_ref_rt

from colcommon.frames import Frame, decode_frame, encode_frame
from companion.vision.perception import PadDetector
from sitl.camera import CameraRenderer
from sitl.config import CameraConfig, WorldConfig
from sitl.world import World

TOUCHDOWN_HEIGHT_M = 0.3  # camera above the pad when the landing gear touches it
MAX_TILT_RAD = math.radians(20.0)
RIM_POINTS = 90


def sample_pose(rng: np.random.Generator, pad_ned: np.ndarray, start_height_m: float):
    """A camera pose around the pad: (position_ned_m, attitude_rad)."""
    height_m = rng.uniform(TOUCHDOWN_HEIGHT_M, start_height_m)
    reach_m = 1.1 * height_m + 0.5
    offset_ne = rng.uniform(-reach_m, reach_m, size=2)
    position = pad_ned + np.array([offset_ne[0], offset_ne[1], -height_m])
    attitude = np.array([rng.uniform(-MAX_TILT_RAD, MAX_TILT_RAD), rng.uniform(-MAX_TILT_RAD, MAX_TILT_RAD), rng.uniform(-math.pi, math.pi)])
    return position, attitude


def truth(renderer: CameraRenderer, pad_ned: np.ndarray, radius_m: float, position, attitude) -> dict:
    """Where the pad is in the image: ``view`` is 'full', 'partial', 'out' or 'behind'."""
    angles = np.linspace(0.0, 2 * math.pi, RIM_POINTS, endpoint=False)
    rim = pad_ned + radius_m * np.column_stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)])
    uvd = renderer.project_many(rim, position, attitude)
    if np.any(uvd[:, 2] <= 0):
        return {"view": "behind"}
    poly = uvd[:, :2].astype(np.float32)
    w, h = renderer.width_px, renderer.height_px
    centre = renderer.project(pad_ned, position, attitude)
    radius = math.sqrt(abs(cv2.contourArea(poly)) / math.pi)
    inside = (poly[:, 0] >= 0) & (poly[:, 0] <= w - 1) & (poly[:, 1] >= 0) & (poly[:, 1] <= h - 1)
    if inside.all():
        return {"view": "full", "centre": centre, "radius": radius}
    rect = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5]], np.float32)
    overlap, _ = cv2.intersectConvexConvex(cv2.convexHull(poly), rect)
    return {"view": "out" if overlap <= 0 else "partial", "centre": centre, "radius": radius}


def perturb(image: np.ndarray, rng: np.random.Generator, conditions: dict) -> np.ndarray:
    """Optional lighting gain (0.4-1.6), motion blur (3 to 7 px, any direction), sensor noise
    (Gaussian, sigma 8 levels) and the JPEG wire encoding, in that order."""
    lighting, blur, noise, jpeg = (conditions[k] for k in ("lighting", "blur", "noise", "jpeg"))
    if lighting:
        image = cv2.convertScaleAbs(image, alpha=float(rng.uniform(0.4, 1.6)))
    if blur:
        half = int(rng.integers(1, 4))  # kernel 3..7 px, centred: blur about the exposure's middle
        angle = rng.uniform(0.0, math.pi)
        dx, dy = round(half * math.cos(angle)), round(half * math.sin(angle))
        kernel = np.zeros((2 * half + 1, 2 * half + 1), np.float32)
        cv2.line(kernel, (half - dx, half - dy), (half + dx, half + dy), 1.0, 1)
        image = cv2.filter2D(image, -1, kernel / kernel.sum())
    if noise:
        image = np.clip(image + rng.normal(0.0, 8.0, image.shape), 0, 255).astype(np.uint8)
    if jpeg:
        image = decode_frame(encode_frame(Frame(0, 0, image), "jpeg")).image
    return image


def run(frames: int, seed: int, conditions: dict) -> dict:
    """``conditions``: booleans ``lighting``, ``blur``, ``noise``, ``jpeg`` (see perturb)."""
    rng = np.random.default_rng(seed)
    world_cfg = WorldConfig()
    renderer = CameraRenderer(CameraConfig(), World(world_cfg))
    detector = PadDetector()
    pad = renderer.world.pad_ned(0.0)
    centre_err, radius_err, render_ms, detect_ms, partial_err = [], [], [], [], []
    render_cpu_ms, detect_cpu_ms = [], []
    counts = {"full": 0, "partial": 0, "out": 0, "behind": 0, "miss": 0, "false_positive": 0, "partial_found": 0}
    for _ in range(frames):
        position, attitude = sample_pose(rng, pad, world_cfg.start_height_above_pad_m)
        c0, t0 = time.thread_time_ns(), time.perf_counter()
        image = renderer.render(position, attitude, 0.0)
        c1, t1 = time.thread_time_ns(), time.perf_counter()
        image = perturb(image, rng, conditions)
        c2, t2 = time.thread_time_ns(), time.perf_counter()
        found = detector.detect(image)
        c3, t3 = time.thread_time_ns(), time.perf_counter()
        render_ms.append((t1 - t0) * 1e3)
        detect_ms.append((t3 - t2) * 1e3)
        render_cpu_ms.append((c1 - c0) / 1e6)
        detect_cpu_ms.append((c3 - c2) / 1e6)
        gt = truth(renderer, pad, world_cfg.pad_radius_m, position, attitude)
        counts[gt["view"]] += 1
        if gt["view"] == "out" and found is not None:
            counts["false_positive"] += 1
        elif gt["view"] == "partial" and found is not None:
            counts["partial_found"] += 1
            partial_err.append(math.hypot(found.u_px - gt["centre"][0], found.v_px - gt["centre"][1]))
        elif gt["view"] == "full":
            if found is None:
                counts["miss"] += 1
                continue
            centre_err.append(math.hypot(found.u_px - gt["centre"][0], found.v_px - gt["centre"][1]))
            radius_err.append(abs(found.radius_px - gt["radius"]) / gt["radius"])
    errors = {"centre": centre_err, "radius": radius_err, "partial_centre": partial_err}
    result = summarise(counts, errors, render_ms, detect_ms, frames, {"seed": seed, **conditions})
    result["render_cpu_ms_p50"] = round(float(np.percentile(render_cpu_ms, 50)), 4)
    result["detect_cpu_ms_p50"] = round(float(np.percentile(detect_cpu_ms, 50)), 4)
    return result


def summarise(counts, errors, render_ms, detect_ms, frames, conditions) -> dict:
    def pct(values, q):
        return round(float(np.percentile(values, q)), 4) if values else None

    return {
        "center_err_px_p50": pct(errors["centre"], 50),
        "center_err_px_p95": pct(errors["centre"], 95),
        "radius_err_rel_p95": pct(errors["radius"], 95),
        "false_positive_rate": round(counts["false_positive"] / max(counts["out"], 1), 4),
        "miss_rate": round(counts["miss"] / max(counts["full"], 1), 4),
        "render_ms_p50": pct(render_ms, 50),
        "detect_ms_p50": pct(detect_ms, 50),
        "partial_detected_rate": round(counts["partial_found"] / max(counts["partial"], 1), 4),
        "partial_center_err_px_p50": pct(errors["partial_centre"], 50),
        "partial_center_err_px_p95": pct(errors["partial_centre"], 95),
        "frames": frames, "frames_full": counts["full"], "frames_partial": counts["partial"],
        "frames_out": counts["out"], **conditions,
        "note": "times measured on a shared machine",
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="100 frames instead of 600")
    parser.add_argument("--frames", type=int, default=None)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--lighting", action="store_true", help="random brightness gain per frame")
    parser.add_argument("--blur", action="store_true", help="random motion blur per frame")
    parser.add_argument("--noise", action="store_true", help="Gaussian sensor noise, sigma 8 levels")
    parser.add_argument("--jpeg", action="store_true", help="send frames through the JPEG wire encoding")
    parser.add_argument("--cv-threads", type=int, default=1,
                        help="cv2.setNumThreads (1, as in the experiment; 0: OpenCV's default)")
    args = parser.parse_args()
    if args.cv_threads > 0:
        cv2.setNumThreads(args.cv_threads)
    machine_ref = machine_ref_rt()  # at the start, before the bench's own work
    frames = args.frames or (100 if args.quick else 600)
    conditions = {k: getattr(args, k) for k in ("lighting", "blur", "noise", "jpeg")}
    result = run(frames, args.seed, conditions)
    result["cv_threads"] = cv2.getNumThreads()
    result["load_avg_1min"] = round(os.getloadavg()[0], 2)
    result["machine_ref_rt"] = round(machine_ref, 1)
    print(json.dumps(result))


if __name__ == "__main__":
    main()
