"""The SITL's camera: rendered from the vehicle's true pose and streamed to its readers.

Frames go to the ``colf://`` TCP stream (sitl/frames.py) or to a reader in the same process,
and, when asked for, as H.264 over RTP to ground stations (sitl/rtp.py). In real time they run
on their own clock (``stream_rate_hz``); in lockstep the server publishes every frame's own
image before its marker (sitl/server.py).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from sitl.config import SitlConfig

if TYPE_CHECKING:
    from colcommon.frames import Frame
    from sitl.camera import CameraRenderer
    from sitl.vehicle import SimVehicle

M = mavlink
WRITE_TIMEOUT_S = 2.0  # real time: a reader this far behind is dropped (sitl/frames.py)


def render_frame(renderer: CameraRenderer, v: SimVehicle) -> np.ndarray:
    """The camera's image now: the true pose (``frame_latency`` ago) through the camera as
    mounted, with the episode's pixel noise; stamped by the caller with the current time."""
    s = v.camera_state
    d = v.disturbance
    image = renderer.render(s.position_ned_m, s.attitude_rad, s.time_s, d.camera_mount)
    return d.add_image_noise(image, v.dynamics.steps)


def reader_patience_s(cfg: SitlConfig) -> float:
    """How long a frame may take to reach a reader before the reader is dropped. In lockstep
    as long as the SITL waits for the frame's answer: the companion that reads the camera is the
    one that answers, and a machine that starves both for a few seconds (seen at a load of 10+
    on 2 cores) otherwise lost the reader, and the frames of the next steps, while the answer
    was still awaited; the flight then differed from the same run on an idle machine."""
    if cfg.clock.mode == "lockstep":
        return max(WRITE_TIMEOUT_S, cfg.clock.lockstep_timeout_s)
    return WRITE_TIMEOUT_S


class FrameSink(Protocol):
    """Where the camera's frames go: :class:`~sitl.frames.FrameServer` (TCP readers), or a
    reader in the same process."""

    @property
    def uri(self) -> str: ...

    @property
    def port(self) -> int: ...

    @property
    def client_count(self) -> int: ...

    def publish(self, frame: Frame, blocking: bool) -> None: ...

    def close(self) -> None: ...


class CameraFeed:
    """Renders the downward camera from the true pose and publishes it on the frame server
    (or on ``sink``), and says the camera component is there (its HEARTBEAT)."""

    def __init__(self, cfg: SitlConfig, vehicle: SimVehicle, sink: FrameSink | None = None) -> None:
        from sitl.camera import CameraRenderer
        from sitl.frames import FrameServer

        self.vehicle = vehicle
        self.renderer = CameraRenderer(cfg.camera, vehicle.world)
        self.server: FrameSink = sink if sink is not None else FrameServer(
            cfg.network.host, cfg.network.camera_port, encoding=cfg.camera.encoding,
            jpeg_quality=cfg.camera.jpeg_quality, write_timeout_s=reader_patience_s(cfg))
        self.frame_number = 0
        self.interval_s = 1.0 / cfg.camera.stream_rate_hz
        self._next_s = 0.0
        self._next_heartbeat_s = 0.0
        self.rtp = None
        if cfg.network.rtp_video:
            from sitl.rtp import RtpVideoSender

            rate = cfg.camera.stream_rate_hz if cfg.clock.mode == "realtime" else cfg.clock.frame_rate_hz
            self.rtp = RtpVideoSender(cfg.network.rtp_video, cfg.camera.width_px, cfg.camera.height_px, rate)

    def publish_if_due(self, blocking: bool) -> None:
        """Real time: frames on their own clock (stream_rate_hz of simulation time)."""
        t = self.vehicle.time_s
        if t + 1e-9 >= self._next_s:
            self._next_s = max(self._next_s + self.interval_s, t)
            self.publish(blocking)

    def publish(self, blocking: bool) -> None:
        from colcommon.frames import Frame

        rtp = self.rtp if self.rtp is not None and self.rtp.alive else None
        if self.server.client_count == 0 and rtp is None:
            return
        image = render_frame(self.renderer, self.vehicle)
        if self.server.client_count:
            self.server.publish(Frame(self.frame_number, self.vehicle.time_boot_ms, image), blocking=blocking)
        if rtp is not None:
            rtp.publish(image)
        self.frame_number += 1

    def heartbeat(self, time_s: float) -> mavlink.MAVLink_message | None:
        """The camera component's HEARTBEAT when one is due (1 Hz of simulation time)."""
        if time_s < self._next_heartbeat_s:
            return None
        self._next_heartbeat_s = time_s + 1.0
        return M.MAVLink_heartbeat_message(M.MAV_TYPE_CAMERA, M.MAV_AUTOPILOT_INVALID, 0, 0, M.MAV_STATE_ACTIVE, 3)

    def rebase_clock(self, shift_s: float) -> None:
        """The simulation clock went back ``shift_s`` at an episode reset: the next HEARTBEAT
        keeps its place on the boot clock."""
        self._next_heartbeat_s -= shift_s

    def close(self) -> None:
        self.server.close()
        if self.rtp is not None:
            self.rtp.close()
