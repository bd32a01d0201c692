"""One vehicle behind a link as a lane of the episode core (companion/control/lanes.py).

:class:`LinkLane` is the core's vehicle port (:class:`~companion.control.lanes.LanePort`) on a
MAVLink link to a lockstep SITL (over sockets, or the in-process one): the session's episode start
(:class:`~companion.control.episode_start.EpisodeStart`: the simulator's reset, the setpoint
stream, OFFBOARD), its frames (:class:`~companion.control.link_port.LinkPort`: each setpoint
answers its frame), and the camera frame stamped with the telemetry's frame, as the session's
observer takes it. So a driver that flies one vehicle step by step (the Gymnasium env) flies it
through the same core as the batched drivers, with the session's own parts for the link.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from companion.commands import CommandMapper
from companion.config import CompanionConfig, SessionConfig
from companion.control.episode_start import EpisodeStart
from companion.control.lanes import ACCEPTED, START_ATTEMPTS, start_with_retries
from companion.control.link_port import HOLD, LinkPort
from companion.control.precland import PrecisionLander
from companion.control.safety import Geofence
from companion.errors import ColError, LinkLost
from companion.link.base import VehicleLink
from companion.link.home import HomeFrame
from companion.link.sim_params import AutopilotSim
from companion.link.truth import TRUTH_RATE_HZ
from companion.msg.setpoint import VelocitySetpoint
from companion.msg.snapshot import VehicleSnapshot
from companion.simulator import SimulatorClient
from companion.vision.camera import CameraSource, lockstep_frame

MAV_RESULT_FAILED = 4


@dataclass
class _StartParts:
    """What the session's episode start reads of its parts (EpisodeStart's StartParts)."""

    cfg: SessionConfig
    simulator: SimulatorClient | None
    lander: PrecisionLander | None = None
    truth_rate_hz: float = TRUTH_RATE_HZ
    autopilot_sim: AutopilotSim | None = None  # a lane always has our simulator: it resets, never flies to a start


class LinkLane:
    """A lockstep vehicle behind ``link``, reset through ``simulator`` (module docstring)."""

    def __init__(self, cfg: CompanionConfig, link: VehicleLink, simulator: SimulatorClient,
                 camera: CameraSource | None, image_size_px: tuple[int, int]) -> None:
        self.home = HomeFrame()
        self.fence = Geofence.from_config(cfg.safety)
        self.mapper = CommandMapper(cfg.commands)  # repairs of this vehicle's commands, counted and logged
        self.image_size_px = image_size_px
        self.port = LinkPort(link, True, cfg.session.control_rate_hz, self.home)
        self.starter = EpisodeStart(self.port, _StartParts(cfg.session, simulator), lambda: self.port.dialect)
        self.simulator = simulator
        self.camera = camera
        self.frame_timeout_s = cfg.perception.frame_timeout_s

    def begin(self, seed: int | None, attempts: int = START_ATTEMPTS) -> VehicleSnapshot:
        """The session's start (a link error tries again, ``attempts`` in all): the first frame."""
        return start_with_retries(lambda s: self.starter.start(s)[0], seed, attempts)

    def velocity(self, forward_right_down_m_s: tuple[float, float, float], yaw_rate_rad_s: float) -> None:
        self.port.send(VelocitySetpoint(*forward_right_down_m_s, yaw_rate_rad_s))

    def hold(self) -> None:
        self.port.send(HOLD)

    def request_hold_mode(self) -> tuple[int, str]:
        try:
            self.port.link.set_mode(self.port.dialect.hold_mode)
        except ColError as exc:
            return MAV_RESULT_FAILED, str(exc)
        return ACCEPTED, ""

    def next_frame(self) -> VehicleSnapshot:
        """The next frame's telemetry; LinkLost if none comes in time (a starved SITL)."""
        snap = self.port.next_snapshot()
        if snap is None:
            raise LinkLost("no frame from the SITL in time")
        return snap

    def image(self) -> np.ndarray | None:
        """The camera image of the frame being answered (None: no camera, or none in time)."""
        if self.camera is None:
            return None
        frame = lockstep_frame(self.camera, self.port.frame_ms, self.frame_timeout_s)
        return None if frame is None else frame.image

    def ground_truth(self) -> dict[str, Any]:
        return self.simulator.truth()
