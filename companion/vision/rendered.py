"""A camera for vehicles that have none: our renderer and pad world driven by the vehicle's own
telemetry (``--camera render``).

Real PX4 SIH and ArduCopter SITL render nothing. This source renders, at ``rate_hz``, the
downward view our SITL would render for the pose the vehicle reports: LOCAL_POSITION_NED (height
taken from the ground the vehicle stood on, as the session takes it: companion/link/home.py)
and ATTITUDE, with the pad at ``pad_ne_m`` of the vehicle's local frame on the ground vehicle of ``[sitl.world]`` (static, or driving at its set velocity from the first frame).

Why the companion's own telemetry and not a second MAVLink connection: it is the very estimate
the observation is built from (a frame and its observation agree on the pose), it needs no
second port (ArduCopter SITL sends its telemetry to one client), and the frame's age is exact:
each frame carries the ``time_boot_ms`` of the telemetry it was rendered from. When telemetry
stops (nothing newer for ``stale_after_s``) no frame is made: the source reports "no telemetry"
and the observation says the pad is not visible, never an old frame as a fresh one.

What this is not: the vehicle's true pose (the estimate drifts; the picture follows the estimate,
as a camera fixed to the vehicle would not) and not a physical pad: the vehicle lands on the
autopilot's own ground, so use a ground vehicle of height 0 there (``vehicle_height_m = 0``).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

import numpy as np

from colcommon.frames import Frame
from companion.link.home import HomeFrame
from companion.msg.snapshot import VehicleSnapshot
from sitl.camera import CameraRenderer
from sitl.config import CameraConfig, WorldConfig
from sitl.world import World

log = logging.getLogger(__name__)
RENDER_SCHEME = "render"


class RenderedCamera:
    """A :class:`~companion.vision.camera.CameraSource` rendering from a snapshot provider."""

    vehicle_time_stamps = True  # each frame carries the time_boot_ms of the telemetry it shows

    def __init__(self, state: Callable[[], VehicleSnapshot | None], camera: CameraConfig, world: WorldConfig,
                 pad_ne_m: tuple[float, float] = (0.0, 0.0), rate_hz: float = 30.0, stale_after_s: float = 0.5,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if rate_hz <= 0:
            raise ValueError(f"rate_hz must be > 0, got {rate_hz}")
        self._state, self._clock = state, clock
        self._world = World(world)
        self._renderer = CameraRenderer(camera, self._world)
        self.pad_ne_m = (float(pad_ne_m[0]), float(pad_ne_m[1]))
        self.success_radius_m = world.success_radius_m
        self.period_s, self.stale_after_s = 1.0 / rate_hz, stale_after_s
        self.home = HomeFrame()
        self._cond = threading.Condition()
        self._frame: Frame | None = None
        self._number = 0
        self._t0_ms: int | None = None
        self._last_rendered_ms: int | None = None
        self.no_telemetry: str | None = "no telemetry yet"
        self.render_times_s: list[float] = []
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # ----- CameraSource ------------------------------------------------------------------------
    def open(self) -> None:
        self._thread = threading.Thread(target=self._run, name="rendered-camera", daemon=True)
        self._thread.start()

    def latest(self) -> Frame | None:
        with self._cond:
            return self._frame if self.no_telemetry is None else None

    def frame_at(self, time_boot_ms: int, timeout_s: float) -> Frame | None:
        """The first frame rendered from telemetry at or after ``time_boot_ms``."""
        deadline = self._clock() + timeout_s
        with self._cond:
            while True:
                frame = self._frame if self.no_telemetry is None else None
                if frame is not None and frame.time_boot_ms >= time_boot_ms:
                    return frame
                left = deadline - self._clock()
                if left <= 0:
                    return None
                self._cond.wait(left)

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)

    # ----- rendering ---------------------------------------------------------------------------
    def world_pose(self, snap: VehicleSnapshot) -> tuple[tuple[float, float, float], float]:
        """(position in the pad's world, world time in s) for a snapshot: north/east from the pad,
        down from the ground the vehicle stood on."""
        n, e, d = self.home.relative(snap)
        if self._t0_ms is None:
            self._t0_ms = snap.time_boot_ms
        t_s = max(0.0, (snap.time_boot_ms - self._t0_ms) / 1000.0)
        return (n - self.pad_ne_m[0], e - self.pad_ne_m[1], d), t_s

    def render(self, snap: VehicleSnapshot) -> Frame:
        """The frame for one snapshot (also what the thread publishes)."""
        position, t_s = self.world_pose(snap)
        image = self._renderer.render(position, snap.attitude_rad, t_s)
        return Frame(self._number, max(0, int(snap.time_boot_ms)), image)

    def step(self) -> Frame | None:
        """Render once from the newest telemetry, unless it is stale or already rendered."""
        snap = self._state()
        now = self._clock()
        if snap is None or not (snap.position_valid and snap.attitude_valid):
            self._starved("no position and attitude from the vehicle yet")
            return None
        self.home.update(snap)
        if now - snap.received_s > self.stale_after_s:
            self._starved(f"no telemetry for {now - snap.received_s:.1f} s")
            return None
        if snap.time_boot_ms == self._last_rendered_ms:
            return None
        start = time.perf_counter()
        try:
            frame = self.render(snap)
        except ValueError as exc:  # a non-finite pose: no picture of it
            self._starved(f"unusable pose: {exc}")
            return None
        self.render_times_s.append(time.perf_counter() - start)
        if len(self.render_times_s) > 10_000:
            del self.render_times_s[:5_000]
        self._number += 1
        self._last_rendered_ms = snap.time_boot_ms
        with self._cond:
            if self.no_telemetry is not None:
                log.info("rendered camera: telemetry back, frames resume")
            self._frame, self.no_telemetry = frame, None
            self._cond.notify_all()
        return frame

    def _starved(self, reason: str) -> None:
        with self._cond:
            if self.no_telemetry is None:
                log.warning("rendered camera: %s; no frames until it resumes", reason)
            self.no_telemetry = reason
            self._cond.notify_all()
        return None

    def _run(self) -> None:
        next_s = self._clock()
        while not self._stop.is_set():
            try:
                self.step()
            except Exception:  # a renderer bug must not kill the flight: no frames, logged
                log.exception("rendered camera failed a frame")
            next_s += self.period_s
            delay = next_s - self._clock()
            if delay <= 0:
                next_s = self._clock()
            elif self._stop.wait(delay):
                break


def render_times_ms(camera: RenderedCamera) -> dict[str, float]:
    """p50/p95 of the render time, for summaries and benches."""
    if not camera.render_times_s:
        return {}
    arr = np.asarray(camera.render_times_s) * 1e3
    return {"render_p50_ms": round(float(np.percentile(arr, 50)), 3), "render_p95_ms": round(float(np.percentile(arr, 95)), 3)}
