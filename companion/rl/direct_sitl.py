"""One lockstep SITL vehicle driven by direct calls: the SITL side of the batched landing env.

:class:`~companion.inprocess.InProcessSitl` runs the SITL server's frame loop and
hands every message over as the companion's parser would make it (composed, packed, unpacked,
folded into a new snapshot). :class:`DirectSitl` keeps what of that decides an episode and drops
the messages themselves:

- the vehicle (JSBSim and the autopilot cascade) is :func:`sitl.personality.make_vehicle`'s, built
  from the same configuration (:func:`~companion.inprocess.inprocess_config`);
- a frame is the server's lockstep frame: ``frame_steps`` FDM steps, then the streams that the
  server's :class:`~sitl.telemetry.TelemetryScheduler` says are due, then the frame marker
  (SYSTEM_TIME); the image is the server's :func:`~sitl.camera_feed.render_frame` (pixel noise and
  camera latency included), decoded from JPEG when the stream would be;
- what the link would hold after the frame is a :class:`~companion.link.base.VehicleSnapshot`
  with the fields the companion's telemetry handlers (:mod:`companion.link.telemetry`) set from
  each due message, from the same values the message composers use
  (:mod:`sitl.telemetry`'s ``*_fields``), rounded to float32 as the wire rounds them (the same
  ``struct`` packing as pymavlink); a message with a non-finite value is dropped whole, as there;
  streams no handler reads (SYS_STATUS, VFR_HUD, ...) change nothing and are not composed;
- a velocity setpoint reaches :meth:`SimVehicle.offboard_setpoint` as the message handler
  passes it (:class:`~sitl.offboard.TargetFields`, float32), an episode reset goes through the
  control surface's :func:`~sitl.control_surface.handle_request` and restarts the scheduler as
  the server does, a mode request calls the vehicle as the handler does.

Left out, because they carry nothing an episode depends on: MAVLink framing and sequence
numbers, COMMAND_ACKs and STATUSTEXTs (the vehicle's events are dropped every frame, as the
server flushes them), the camera component's HEARTBEAT, the wall-clock times the link keeps
(``received_s``, ``heartbeat_s``: 0 here), and images of frames nobody looks at (an image is
rendered when asked for, from the frame's end state, which nothing changes before the next
frame or reset).
"""

from __future__ import annotations

import json
import math
import struct
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

import companion.link.px4_modes as px4_modes
from colcommon.frames import Frame, decode_frame, encode_frame
from companion.config import LinkConfig
from companion.errors import ConfigError, LinkTimeout, SimulatorError
from companion.inprocess import inprocess_config
from companion.link.mavlink_link import default_rates_hz, interval_params
from companion.link.telemetry import initial_snapshot, with_changes
from companion.link.wire_copy import wire_copy
from companion.msg.snapshot import LANDED_STATES, VehicleSnapshot
from sitl.camera_feed import render_frame
from sitl.clock import frame_steps
from sitl.config import SitlConfig
from sitl.control_surface import RequestError, handle_request, truth
from sitl.handler import AUTOPILOT
from sitl.offboard import TargetFields
from sitl.personality import make_vehicle
from sitl.telemetry import (
    COMPOSERS,
    TelemetryScheduler,
    attitude_fields,
    home_local,
    local_position_fields,
)
from sitl.vehicle import SimVehicle

M = mavlink
CONNECT_TIMEOUT_S = 30.0  # as LandingEnv's link.connect
_FLOAT32 = {n: struct.Struct(f"<{n}f") for n in (2, 3, 4, 6)}
Changes = dict[str, Any]


def wire_floats(values: Sequence[float]) -> tuple[float, ...]:
    """``values`` as a MAVLink float field carries them: packed to float32 by the same ``struct``
    conversion as pymavlink's, read back as Python floats."""
    packer = _FLOAT32[len(values)]
    return packer.unpack(packer.pack(*values))


def _finite(values: Sequence[float]) -> bool:
    return all(math.isfinite(v) for v in values)


# Each fold gives the snapshot fields one due message would set (empty: it would be dropped).
def _local_position(v: SimVehicle) -> Changes:
    time_boot_ms, *values = local_position_fields(v)
    x, y, z, vx, vy, vz = wire_floats(values)
    if not _finite((x, y, z, vx, vy, vz)):
        return {}
    return {"time_boot_ms": time_boot_ms, "position_ned_m": (x, y, z), "velocity_ned_m_s": (vx, vy, vz),
            "position_valid": True}


def _attitude(v: SimVehicle) -> Changes:
    time_boot_ms, *values = attitude_fields(v)
    roll, pitch, yaw, p, q, r = wire_floats(values)
    if not _finite((roll, pitch, yaw, p, q, r)):
        return {}
    return {"time_boot_ms": time_boot_ms, "attitude_rad": (roll, pitch, yaw), "rates_frd_rad_s": (p, q, r),
            "attitude_valid": True}


def _extended_sys_state(v: SimVehicle) -> Changes:
    state = int(v.landed_state)
    return {"landed_state": LANDED_STATES[state] if state < len(LANDED_STATES) else "UNDEFINED"}


def _home_position(v: SimVehicle) -> Changes:
    home = wire_floats(home_local(v))
    return {"home_ned_m": home} if _finite(home) else {}


def _heartbeat(v: SimVehicle) -> Changes:
    """A PX4 HEARTBEAT (the only lockstep personality): armed flag and PX4 mode name."""
    return {"armed": bool(v.armed), "mode": px4_modes.decode(v.heartbeat_mode()[1])}


FOLDS: dict[int, Callable[[SimVehicle], Changes]] = {
    M.MAVLINK_MSG_ID_HEARTBEAT: _heartbeat,
    M.MAVLINK_MSG_ID_LOCAL_POSITION_NED: _local_position,
    M.MAVLINK_MSG_ID_ATTITUDE: _attitude,
    M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: _extended_sys_state,
    M.MAVLINK_MSG_ID_HOME_POSITION: _home_position,
}
"""The due streams the companion's link reads (companion/link/telemetry.py ``HANDLERS``)."""


class DirectSitl:
    """One SITL vehicle with its camera, stepped a lockstep frame at a time (module docstring)."""

    def __init__(self, cfg: SitlConfig, link: LinkConfig) -> None:
        if link.frame_marker != "SYSTEM_TIME":
            raise ConfigError(f"the batched env runs lockstep, whose frame marker is SYSTEM_TIME, not {link.frame_marker}")
        self.cfg = inprocess_config(cfg)
        self.link_cfg = link
        self.vehicle: SimVehicle = make_vehicle(self.cfg)
        if not self.vehicle.sends_frame_marker or self.vehicle.heartbeat_mode()[0] != M.MAV_AUTOPILOT_PX4:
            raise ConfigError("the batched env flies the SITL's PX4 personality (lockstep needs its frame marker)")
        self.scheduler = TelemetryScheduler(self.vehicle.default_rates_hz)
        self.steps_per_frame = frame_steps(self.cfg)
        self.renderer = None
        if self.cfg.camera.enabled:
            from sitl.camera import CameraRenderer

            self.renderer = CameraRenderer(self.cfg.camera, self.vehicle.world)
        self.reported: VehicleSnapshot | None = None
        """What the link would hold after the latest frame (None before the first HEARTBEAT)."""
        self._image: np.ndarray | None = None
        self._frames = 0

    # ----- the link's side -----------------------------------------------------------------
    def connect(self) -> VehicleSnapshot:
        """As ``MavlinkLink.connect`` on the in-process SITL: frames until the vehicle's first
        HEARTBEAT, then the streams the companion asks for (SET_MESSAGE_INTERVAL)."""
        for _ in range(max(1, math.ceil(CONNECT_TIMEOUT_S * self.cfg.clock.frame_rate_hz))):
            if self.reported is not None:
                break
            self.advance()
        if self.reported is None:
            raise LinkTimeout(f"no HEARTBEAT from the simulated vehicle within {CONNECT_TIMEOUT_S} s")
        if self.link_cfg.request_rates_on_connect:
            for name, hz in default_rates_hz(self.link_cfg).items():
                msg_id, interval_us = wire_floats(interval_params(name, hz))
                if math.isfinite(msg_id) and math.isfinite(interval_us):  # the message handler's test
                    self.scheduler.set_interval(int(msg_id), interval_us, self.vehicle.time_s)
        return self.reported

    # ----- the SITL's side -------------------------------------------------------------------
    def reset(self, seed: int | None) -> dict[str, Any]:
        """The control surface's episode reset, as the in-process SITL answers it (the reply as
        its client reads it back); SimulatorError when it refuses, as the client raises."""
        try:
            reply = handle_request(self.vehicle, {"cmd": "reset", "seed": seed}, None, self.cfg.clock.mode)
        except RequestError as exc:
            raise SimulatorError(f"simulator refused 'reset': {exc}") from None
        self.scheduler = self.scheduler.restarted(self.vehicle.default_rates_hz, self.vehicle.time_s)
        self.vehicle.events.clear()
        self._image = None
        return dict(json.loads(json.dumps(reply)))

    def command_velocity(self, frame: int, type_mask: int, velocity: Sequence[float], yaw_rate_rad_s: float) -> None:
        """SET_POSITION_TARGET_LOCAL_NED with a velocity and a yaw rate (position and yaw 0), as
        the message handler hands it to the vehicle after the wire."""
        vx, vy, vz, yaw_rate = wire_floats((*velocity, yaw_rate_rad_s))
        self.vehicle.offboard_setpoint(TargetFields(frame, type_mask, 0.0, 0.0, 0.0, vx, vy, vz, 0.0, yaw_rate))

    def request_mode(self, name: str) -> tuple[int, str]:
        """MAV_CMD_DO_SET_MODE with PX4's main and sub mode: the vehicle's (result, why)."""
        main, sub = px4_modes.encode(name)
        return self.vehicle.set_mode_numbers(main, sub)

    def arm(self) -> tuple[int, str]:
        """MAV_CMD_COMPONENT_ARM_DISARM (arm, not forced): the vehicle's (result, why)."""
        return self.vehicle.arm(False)

    def advance(self) -> VehicleSnapshot | None:
        """One lockstep frame: the vehicle's steps, then what the link would hold after it."""
        v = self.vehicle
        for _ in range(self.steps_per_frame):
            v.step()
        due = self.scheduler.due(v.time_s)
        self._frames += 1
        self._image = None
        self.reported = self._fold(due)
        v.events.clear()  # the server flushes them as STATUSTEXT every frame
        return self.reported

    def _fold(self, due: list[int]) -> VehicleSnapshot | None:
        """The snapshot after this frame's due messages and its SYSTEM_TIME marker."""
        v = self.vehicle
        snap = self.reported
        if snap is None:  # the link adopts the vehicle at its first HEARTBEAT; before it, nothing is heard
            if M.MAVLINK_MSG_ID_HEARTBEAT not in due:
                return None
            due = due[due.index(M.MAVLINK_MSG_ID_HEARTBEAT) + 1:]
            snap = self._adopt()
        changes: Changes = {}
        for msg_id in due:
            fold = FOLDS.get(msg_id)
            if fold is not None:
                changes.update(fold(v))
        frame_ms = v.time_boot_ms
        changes.update(time_boot_ms=frame_ms, frame_time_boot_ms=frame_ms)
        return with_changes(snap, changes)

    def _adopt(self) -> VehicleSnapshot:
        """The link's first snapshot, from the vehicle's first HEARTBEAT (made and read once as
        on the wire: the in-process SITL's hand-over)."""
        sender = M.MAVLink(None, self.cfg.network.system_id, AUTOPILOT)
        return initial_snapshot(wire_copy(COMPOSERS[M.MAVLINK_MSG_ID_HEARTBEAT](self.vehicle), sender), 0.0)

    def image(self) -> np.ndarray | None:
        """The camera image of the latest frame as the companion receives it (None: no camera)."""
        if self.renderer is None:
            return None
        if self._image is None:
            image = render_frame(self.renderer, self.vehicle)
            cam = self.cfg.camera
            if cam.encoding != "raw":  # lossy: exactly the pixels a reader of the stream decodes
                frame = Frame(self._frames, self.vehicle.time_boot_ms, image)
                image = decode_frame(encode_frame(frame, cam.encoding, cam.jpeg_quality)).image
            self._image = image
        return self._image

    def truth(self) -> dict[str, Any]:
        """The control surface's ground truth, as its client reads it back."""
        return dict(json.loads(json.dumps(truth(self.vehicle))))
