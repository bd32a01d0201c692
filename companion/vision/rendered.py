"""A camera for vehicles that have none: our renderer and pad world driven by the vehicle's own
telemetry (``--camera render``).

Real PX4 SIH and ArduCopter SITL render nothing. This source renders, at ``rate_hz``, the
downward view our SITL would render for the vehicle's pose, with the pad at ``pad_ne_m`` of the
vehicle's local frame on the ground vehicle of ``[sitl.world]`` (static, or driving at its set
velocity, turning and changing speed as configured). A driving pad is put back at ``pad_ne_m``
at each episode's hand-over (:meth:`RenderedCamera.begin_episode`, with the episode's drift from
``[sitl.disturbance]`` where the companion disturbs the autopilot's SITL: companion/link/sim_params.py),
as our SITL's reset puts it, and the touchdown is scored against where it then is
(:meth:`RenderedCamera.pad_ne_at`). The pose is, per frame:

- **the truth** where the autopilot's SITL sends one (the snapshot's ``true_pose``: PX4 SIH's
  HIL_STATE_QUATERNION, ArduPilot's SIM_STATE; companion/link/truth.py) and it is fresh (heard
  within ``stale_after_s``): what a camera on the vehicle would see. Heights are taken from the
  true ground: the true height where the vehicle last stood disarmed, else the local origin's
  altitude. The frame is stamped with the truth's own vehicle time;
- **the estimate** otherwise (a real vehicle, or truth stale or absent): LOCAL_POSITION_NED
  (height taken from the ground the vehicle stood on, as the session takes it:
  companion/link/home.py) and ATTITUDE, stamped with the telemetry's ``time_boot_ms``.

Each frame's source is kept (:meth:`RenderedCamera.source_of`) and counted;
:meth:`RenderedCamera.frame_source_notes` says in the episode record how many frames came from
each (since the last record: the flight to the start included), and, at the frames drawn from
truth, how far the estimate's picture would have been from the truth's (:class:`EstimateError`:
the vehicle's place in the pad's world by its estimate against by its truth): what the camera
drawn from the estimate got wrong. Why the companion's own telemetry and
not a second MAVLink connection: it needs no second port (ArduCopter SITL sends its telemetry to
one client), and the frame's age is exact. When telemetry stops (nothing newer for
``stale_after_s``) no frame is made: the source reports "no telemetry" and the observation says
the pad is not visible, never an old frame as a fresh one.

What this is not: a physical pad: the vehicle lands on the autopilot's own ground, so use a
ground vehicle of height 0 there (``vehicle_height_m = 0``).
"""

from __future__ import annotations

import logging
import statistics
import threading
import time
from collections import Counter, OrderedDict, deque
from collections.abc import Callable
from typing import Literal

import numpy as np

from colcommon.frames import Frame
from companion.link.home import GROUND_DRIFT_M, GROUND_SAMPLES, HomeFrame
from companion.msg.snapshot import Vec3, VehicleSnapshot
from companion.msg.true_pose import TruePose
from sitl.camera import CameraRenderer
from sitl.config import CameraConfig, WorldConfig
from sitl.world import World

log = logging.getLogger(__name__)
RENDER_SCHEME = "render"
PoseSource = Literal["truth", "estimate"]
SOURCES_KEPT = 1000  # frame number -> source, for the newest frames
VEHICLE_CLOCK_POLL_S = 0.002  # by the vehicle's clock: how often the loop looks for a newer pose


class TrueGround:
    """The true ground's down in the local frame: the median true down while the vehicle last
    stood disarmed (a place more than ``GROUND_DRIFT_M`` from the known ground is a raised
    surface), else 0 (the local origin's altitude: ArduPilot SITL's origin is its ground)."""

    def __init__(self) -> None:
        self.down_m: float | None = None
        self._standing: deque[float] = deque(maxlen=GROUND_SAMPLES)
        self._was_standing = False

    def update(self, snap: VehicleSnapshot, pose: TruePose) -> None:
        standing = snap.landed_state == "ON_GROUND" and not snap.armed
        if standing:
            if not self._was_standing:
                self._standing.clear()
            self._standing.append(pose.down_m)
            down = statistics.median(self._standing)
            if self.down_m is None or abs(down - self.down_m) <= GROUND_DRIFT_M:
                self.down_m = down
        self._was_standing = standing

    def relative(self, pose: TruePose) -> Vec3:
        return (pose.north_m, pose.east_m, pose.down_m - (self.down_m or 0.0))


class EstimateError:
    """How far the estimate puts the vehicle from where the truth does, in the pad's world, at
    each frame drawn from truth (horizontal and vertical, metres), since the last :meth:`note`."""

    KEPT = 100_000  # about an hour of frames at 30 Hz

    def __init__(self) -> None:
        self.horizontal_m: deque[float] = deque(maxlen=self.KEPT)
        self.vertical_m: deque[float] = deque(maxlen=self.KEPT)
        self.tilt_rad: deque[float] = deque(maxlen=self.KEPT)
        self.yaw_rad: deque[float] = deque(maxlen=self.KEPT)

    def add(self, estimate: Vec3, truth: Vec3, estimate_rpy: Vec3 = (0.0, 0.0, 0.0),
            truth_rpy: Vec3 = (0.0, 0.0, 0.0)) -> None:
        """One frame's pair of positions (and attitudes: the larger of the roll and pitch
        differences, what tilts the picture; and the heading's, which turns it and turns every
        body-frame velocity the autopilot flies: PX4 SIH's reached 20 degrees)."""
        self.horizontal_m.append(float(np.hypot(estimate[0] - truth[0], estimate[1] - truth[1])))
        self.vertical_m.append(abs(estimate[2] - truth[2]))
        self.tilt_rad.append(max(abs(estimate_rpy[0] - truth_rpy[0]), abs(estimate_rpy[1] - truth_rpy[1])))
        self.yaw_rad.append(abs(float(np.angle(np.exp(1j * (estimate_rpy[2] - truth_rpy[2]))))))

    def note(self, reset: bool = True) -> list[str]:
        """The record's note (none without a pair); ``reset``: the count starts again."""
        if not self.horizontal_m:
            return []
        h, v, tilt = np.asarray(self.horizontal_m), np.asarray(self.vertical_m), np.degrees(self.tilt_rad)
        yaw = np.degrees(self.yaw_rad)
        if reset:
            self.horizontal_m.clear()
            self.vertical_m.clear()
            self.tilt_rad.clear()
            self.yaw_rad.clear()
        return [f"estimate off the truth at {h.size} frames: horizontal median {np.median(h):.3f} m, "
                f"p95 {np.percentile(h, 95):.3f} m, max {h.max():.3f} m; vertical median {np.median(v):.3f} m, "
                f"max {v.max():.3f} m; roll/pitch median {np.median(tilt):.2f} deg, max {tilt.max():.2f} deg; "
                f"yaw median {np.median(yaw):.2f} deg, max {yaw.max():.2f} deg"]


class RenderedCamera:
    """A :class:`~companion.vision.camera.CameraSource` rendering from a snapshot provider."""

    vehicle_time_stamps = True  # each frame carries the time_boot_ms of the telemetry it shows

    def __init__(self, state: Callable[[], VehicleSnapshot | None], camera: CameraConfig, world: WorldConfig,
                 pad_ne_m: tuple[float, float] = (0.0, 0.0), rate_hz: float = 30.0, stale_after_s: float = 0.5,
                 clock: Callable[[], float] = time.monotonic, vehicle_clock: bool = False) -> None:
        if rate_hz <= 0:
            raise ValueError(f"rate_hz must be > 0, got {rate_hz}")
        self._state, self._clock = state, clock
        self._world = World(world)
        self._world_lock = threading.Lock()  # an episode's restart against the render thread's frame
        self._renderer = CameraRenderer(camera, self._world)
        self.pad_ne_m = (float(pad_ne_m[0]), float(pad_ne_m[1]))
        self.success_radius_m = world.success_radius_m
        self.period_s, self.stale_after_s = 1.0 / rate_hz, stale_after_s
        self.vehicle_clock = vehicle_clock
        """Frames at ``rate_hz`` of the vehicle's time, not the wall clock's (an autopilot's SITL run
        faster than real time): the loop polls, and a frame is made once the pose it would show is a
        period newer than the last frame's."""
        self.home = HomeFrame()
        self.true_ground = TrueGround()
        self._cond = threading.Condition()
        self._frame: Frame | None = None
        self._number = 0
        self._t0_ms: int | None = None
        self._last_rendered_ms: int | None = None
        self._last_truth: TruePose | None = None
        self.last_source: PoseSource | None = None
        self.truth_source: str | None = None  # the message the newest truth frame came from
        self.source_counts: Counter[str] = Counter()  # frames per source since the last record's notes
        self.estimate_error = EstimateError()
        self._sources: OrderedDict[int, PoseSource] = OrderedDict()
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
        """(position in the pad's world, world time in s) for a snapshot's estimate: north/east
        from the pad, down from the ground the vehicle stood on."""
        return self._in_world(self.home.relative(snap), snap.time_boot_ms)

    def true_world_pose(self, pose: TruePose) -> tuple[tuple[float, float, float], float]:
        """(position in the pad's world, world time in s) for a true pose: the pad where the
        truth puts it (``pad_ne_m`` of the true local frame), down from the true ground."""
        return self._in_world(self.true_ground.relative(pose), pose.time_boot_ms)

    def _world_time_s(self, time_boot_ms: int) -> float:
        if self._t0_ms is None:
            self._t0_ms = time_boot_ms
        return max(0.0, (time_boot_ms - self._t0_ms) / 1000.0)

    def _in_world(self, ned_m: Vec3, time_boot_ms: int) -> tuple[tuple[float, float, float], float]:
        n, e, d = ned_m
        return (n - self.pad_ne_m[0], e - self.pad_ne_m[1], d), self._world_time_s(time_boot_ms)

    def begin_episode(self, time_boot_ms: int, drift_ne_m_s: tuple[float, float] = (0.0, 0.0)) -> None:
        """The ground vehicle back at ``pad_ne_m`` at the vehicle time ``time_boot_ms`` (the
        episode's hand-over), driving at ``[sitl.world]``'s velocity plus ``drift_ne_m_s`` from
        then on. A still pad stays where it is."""
        with self._world_lock:
            self._world.restart(self._world_time_s(time_boot_ms), drift_ne_m_s)

    def pad_ne_at(self, time_boot_ms: int) -> tuple[float, float]:
        """Where the pad is at the vehicle time ``time_boot_ms``, in the vehicle's local frame."""
        with self._world_lock:
            n, e = self._world.position_ne(self._world_time_s(time_boot_ms))
        return (self.pad_ne_m[0] + float(n), self.pad_ne_m[1] + float(e))

    def render(self, snap: VehicleSnapshot) -> Frame:
        """The frame for one snapshot's estimate."""
        position, t_s = self.world_pose(snap)
        with self._world_lock:
            image = self._renderer.render(position, snap.attitude_rad, t_s)
        return Frame(self._number, max(0, int(snap.time_boot_ms)), image)

    def render_truth(self, pose: TruePose) -> Frame:
        """The frame for one true pose, stamped with the truth's vehicle time."""
        position, t_s = self.true_world_pose(pose)
        with self._world_lock:
            image = self._renderer.render(position, pose.attitude_rad, t_s)
        return Frame(self._number, pose.time_boot_ms, image)

    def fresh_truth(self, snap: VehicleSnapshot, now_s: float) -> TruePose | None:
        """The snapshot's true pose if it is no older than ``stale_after_s``, else None."""
        pose = snap.true_pose
        if pose is None or now_s - pose.received_s > self.stale_after_s:
            return None
        return pose

    def source_of(self, frame_number: int) -> PoseSource | None:
        """What a (recent) frame was rendered from: "truth" or "estimate"."""
        return self._sources.get(frame_number)

    def frame_source_notes(self, reset: bool = True) -> list[str]:
        """For the episode record: how many frames were drawn from truth and from the estimate
        since the last call (``reset``: start counting again)."""
        counts = dict(self.source_counts)
        if reset:
            self.source_counts = Counter()
        if not counts:
            return []
        truth = f" ({self.truth_source})" if counts.get("truth") and self.truth_source else ""
        return [f"rendered camera: {counts.get('truth', 0)} frames from the SITL's truth{truth}, "
                f"{counts.get('estimate', 0)} from the vehicle's estimate", *self.estimate_error.note(reset)]

    def step(self) -> Frame | None:
        """Render once from the newest truth if fresh, else the newest estimate, unless stale or
        already rendered."""
        snap = self._state()
        now = self._clock()
        if snap is None:
            self._starved("no position and attitude from the vehicle yet")
            return None
        if snap.position_valid:
            self.home.update(snap)
        truth = self.fresh_truth(snap, now)
        if truth is not None:
            self.true_ground.update(snap, truth)
            if truth is self._last_truth or self._too_soon(truth.time_boot_ms):
                return None
            frame = self._publish(lambda: self.render_truth(truth), "truth", truth)
            if frame is not None and snap.position_valid:
                self.estimate_error.add(self.world_pose(snap)[0], self.true_world_pose(truth)[0], snap.attitude_rad,
                                        truth.attitude_rad)
            return frame
        if not (snap.position_valid and snap.attitude_valid):
            self._starved("no position and attitude from the vehicle yet")
            return None
        if now - snap.received_s > self.stale_after_s:
            self._starved(f"no telemetry for {now - snap.received_s:.1f} s")
            return None
        if (snap.time_boot_ms == self._last_rendered_ms and self.last_source == "estimate") or self._too_soon(
                snap.time_boot_ms):
            return None
        return self._publish(lambda: self.render(snap), "estimate", None)

    def _publish(self, make: Callable[[], Frame], source: PoseSource, truth: TruePose | None) -> Frame | None:
        start = time.perf_counter()
        try:
            frame = make()
        except ValueError as exc:  # a non-finite pose: no picture of it
            self._starved(f"unusable pose: {exc}")
            return None
        self.render_times_s.append(time.perf_counter() - start)
        if len(self.render_times_s) > 10_000:
            del self.render_times_s[:5_000]
        if source != self.last_source:
            log.info("rendered camera: drawing from %s", f"the SITL's truth ({truth.source})" if truth is not None
                     else "the vehicle's estimate (no fresh truth)")
        self._number += 1
        self._last_rendered_ms, self._last_truth, self.last_source = frame.time_boot_ms, truth, source
        if truth is not None:
            self.truth_source = truth.source
        self.source_counts[source] += 1
        self._sources[frame.frame_number] = source
        if len(self._sources) > SOURCES_KEPT:
            self._sources.popitem(last=False)
        with self._cond:
            if self.no_telemetry is not None:
                log.info("rendered camera: telemetry back, frames resume")
            self._frame, self.no_telemetry = frame, None
            self._cond.notify_all()
        return frame

    def _too_soon(self, time_boot_ms: int) -> bool:
        """By the vehicle's clock: less than a period of its time since the last frame."""
        last = self._last_rendered_ms
        return self.vehicle_clock and last is not None and 0 <= time_boot_ms - last < 1000.0 * self.period_s - 0.5

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
            next_s += VEHICLE_CLOCK_POLL_S if self.vehicle_clock else self.period_s
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
