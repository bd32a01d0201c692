"""Dispatch of received MAVLink messages to the vehicle, and the answers they earn.

Every COMMAND_LONG/COMMAND_INT addressed to us gets exactly one COMMAND_ACK (UNSUPPORTED for
unknown commands); repeating a command is harmless. Parameter protocol with PX4's bytewise
encoding; the camera component (id 100) answers its own requests.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from pymavlink.dialects.v20 import common as mavlink

from sitl.commander import FORCE_DISARM_MAGIC
from sitl.landing_target import LandingTargetRejected, TargetMeasurement
from sitl.offboard import TargetFields
from sitl.params import encode_value
from sitl.telemetry import COMPOSERS, TelemetryScheduler
from sitl.vehicle import SimVehicle

M = mavlink
AUTOPILOT = 1
CAMERA = mavlink.MAV_COMP_ID_CAMERA
NAV_PRECLAND = 23  # PX4's VEHICLE_CMD_NAV_PRECLAND (MAVLink's number of MAV_CMD_NAV_LAND_LOCAL)


@dataclass(frozen=True)
class Outgoing:
    """A message to send: from which of our components, and to whom."""

    component: int
    message: mavlink.MAVLink_message
    to_sender_only: bool = True


@dataclass(frozen=True)
class CameraInfo:
    """What the camera component advertises (the stream is served by the SITL)."""

    uri: str
    width_px: int
    height_px: int
    hfov_deg: float
    framerate_hz: float
    rtp_uri: str | None = None  # the H.264/RTP stream for ground stations, if sent


@dataclass
class HandleResult:
    replies: list[Outgoing]
    lockstep_answer_ms: int | None = None  # echo carried by a setpoint, or -1 for MANUAL_CONTROL


class MessageHandler:
    """Applies one decoded message to the vehicle and returns what to send back."""

    def __init__(self, vehicle: SimVehicle, scheduler: TelemetryScheduler, camera: CameraInfo | None) -> None:
        self.v = vehicle
        self.scheduler = scheduler
        self.camera = camera
        self.sysid = vehicle.cfg.network.system_id
        self.dropped = 0

    def _for_us(self, target_system: int, target_component: int, component: int = AUTOPILOT) -> bool:
        return target_system in (0, self.sysid) and target_component in (0, component)

    def handle(self, msg: mavlink.MAVLink_message) -> HandleResult:
        kind = msg.get_type()
        fn = getattr(self, "_on_" + kind.lower(), None)
        if fn is None:
            return HandleResult([])
        try:
            return fn(msg)
        except (ValueError, TypeError, OverflowError, KeyError) as exc:
            self.dropped += 1
            self.v.say(M.MAV_SEVERITY_WARNING, f"Dropped {kind}: {exc}")
            return HandleResult([])

    # ----- streams -------------------------------------------------------------------------
    def _on_set_position_target_local_ned(self, m: mavlink.MAVLink_message) -> HandleResult:
        if not self._for_us(m.target_system, m.target_component):
            return HandleResult([])
        fields = TargetFields(m.coordinate_frame, m.type_mask, m.x, m.y, m.z, m.vx, m.vy, m.vz, m.yaw, m.yaw_rate)
        self.v.offboard_setpoint(fields)
        return HandleResult([], lockstep_answer_ms=int(m.time_boot_ms))

    def _on_manual_control(self, m: mavlink.MAVLink_message) -> HandleResult:
        if m.target in (0, self.sysid):
            self.v.manual_control(float(m.x), float(m.y), float(m.z), float(m.r))
        return HandleResult([], lockstep_answer_ms=-1)

    def _on_landing_target(self, m: mavlink.MAVLink_message) -> HandleResult:
        """LANDING_TARGET (no target system: every autopilot on the link reads it)."""
        try:
            target = TargetMeasurement(self.v.time_s, float(m.angle_x), float(m.angle_y), float(m.distance), int(m.frame),
                                       bool(getattr(m, "position_valid", 0)), float(m.x), float(m.y), float(m.z),
                                       float(m.size_x), float(m.size_y))
        except LandingTargetRejected as exc:
            self.v.refuse_target(str(exc))
            return HandleResult([])
        self.v.landing_target(target)
        return HandleResult([])

    def _on_set_mode(self, m: mavlink.MAVLink_message) -> HandleResult:
        if m.target_system in (0, self.sysid):
            result, why = self.v.set_mode_custom(m.custom_mode)
            if result != M.MAV_RESULT_ACCEPTED and why:
                self.v.say(M.MAV_SEVERITY_WARNING, why)
        return HandleResult([])

    # ----- parameters ----------------------------------------------------------------------
    def _param_value(self, index: int, to_all: bool = False) -> Outgoing:
        p = self.v.params.by_index(index)
        assert p is not None
        msg = M.MAVLink_param_value_message(p.name.encode(), encode_value(p.value, p.kind), p.kind, len(self.v.params), index)
        return Outgoing(AUTOPILOT, msg, to_sender_only=not to_all)

    def _on_param_request_list(self, m: mavlink.MAVLink_message) -> HandleResult:
        if not self._for_us(m.target_system, m.target_component):
            return HandleResult([])
        return HandleResult([self._param_value(i) for i in range(len(self.v.params))])

    def _on_param_request_read(self, m: mavlink.MAVLink_message) -> HandleResult:
        if not self._for_us(m.target_system, m.target_component):
            return HandleResult([])
        name = _param_name(m.param_id)
        index = m.param_index if m.param_index >= 0 else (self.v.params.index_of(name) if self.v.params.by_name(name) else -1)
        if self.v.params.by_index(index) is None:
            return HandleResult([])
        return HandleResult([self._param_value(index)])

    def _on_param_set(self, m: mavlink.MAVLink_message) -> HandleResult:
        if not self._for_us(m.target_system, m.target_component):
            return HandleResult([])
        name = _param_name(m.param_id)
        if not self.v.set_param(name, m.param_value, m.param_type):
            self.v.say(M.MAV_SEVERITY_WARNING, f"Unknown parameter {name}")
            return HandleResult([])
        # a change is told to every link, as PX4 does, so several ground stations stay in step
        return HandleResult([self._param_value(self.v.params.index_of(name), to_all=True)])

    # ----- commands ------------------------------------------------------------------------
    def _on_command_long(self, m: mavlink.MAVLink_message) -> HandleResult:
        params = (m.param1, m.param2, m.param3, m.param4, m.param5, m.param6, m.param7)
        return self._command(m, params)

    def _on_command_int(self, m: mavlink.MAVLink_message) -> HandleResult:
        params = (m.param1, m.param2, m.param3, m.param4, m.x * 1e-7, m.y * 1e-7, m.z)
        return self._command(m, params)

    def _command(self, m: mavlink.MAVLink_message, p: tuple[float, ...]) -> HandleResult:
        sender = (m.get_srcSystem(), m.get_srcComponent())
        if self.camera is not None and self._for_us(m.target_system, m.target_component, CAMERA) and m.target_component == CAMERA:
            return self._camera_command(m.command, p, sender)
        if not self._for_us(m.target_system, m.target_component):
            return HandleResult([])
        result, text, extra = self._run_command(m.command, p)
        out = [Outgoing(AUTOPILOT, M.MAVLink_command_ack_message(m.command, result, 0, 0, *sender))]
        if text:
            self.v.say(M.MAV_SEVERITY_WARNING if result else M.MAV_SEVERITY_INFO, text)
        return HandleResult(out + extra)

    def _run_command(self, cmd: int, p: tuple[float, ...]) -> tuple[int, str, list[Outgoing]]:
        v = self.v
        if cmd == M.MAV_CMD_COMPONENT_ARM_DISARM:
            force = int(p[1]) == FORCE_DISARM_MAGIC if math.isfinite(p[1]) else False
            result, why = v.arm(force) if p[0] >= 0.5 else v.disarm(force)
            return result, why, []
        if cmd == M.MAV_CMD_NAV_TAKEOFF:
            return (*v.takeoff(p[6]), [])
        if cmd == M.MAV_CMD_NAV_LAND:
            return (*v.land(), [])
        if cmd == M.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN:
            return (*v.reboot(p[0]), [])
        if cmd == NAV_PRECLAND:
            return (*v.precision_land(), [])
        if cmd == M.MAV_CMD_DO_SET_MODE:
            return (*self._set_mode(p), [])
        if cmd == M.MAV_CMD_SET_MESSAGE_INTERVAL:
            ok = math.isfinite(p[0]) and math.isfinite(p[1]) and self.scheduler.set_interval(int(p[0]), p[1], v.time_s)
            return (M.MAV_RESULT_ACCEPTED if ok else M.MAV_RESULT_DENIED), "", []
        if cmd == M.MAV_CMD_REQUEST_MESSAGE:
            return self._request_message(p[0])
        if cmd == M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            return M.MAV_RESULT_ACCEPTED, "", [Outgoing(AUTOPILOT, COMPOSERS[M.MAVLINK_MSG_ID_AUTOPILOT_VERSION](v))]
        return M.MAV_RESULT_UNSUPPORTED, "", []

    def _set_mode(self, p: tuple[float, ...]) -> tuple[int, str]:
        if not (math.isfinite(p[1]) and math.isfinite(p[2])):
            return M.MAV_RESULT_DENIED, "Mode refused: non-finite mode number"
        return self.v.set_mode_numbers(int(p[1]), int(p[2]))

    def _request_message(self, msg_id: float) -> tuple[int, str, list[Outgoing]]:
        composer = COMPOSERS.get(int(msg_id)) if math.isfinite(msg_id) else None
        if composer is None:
            return M.MAV_RESULT_DENIED, "", []
        return M.MAV_RESULT_ACCEPTED, "", [Outgoing(AUTOPILOT, composer(self.v))]

    def _camera_command(self, cmd: int, p: tuple[float, ...], sender: tuple[int, int]) -> HandleResult:
        assert self.camera is not None
        extra: list[Outgoing] = []
        result = M.MAV_RESULT_UNSUPPORTED
        if cmd == M.MAV_CMD_REQUEST_MESSAGE and math.isfinite(p[0]):
            msg_id = int(p[0])
            if msg_id == M.MAVLINK_MSG_ID_CAMERA_INFORMATION:
                extra, result = [Outgoing(CAMERA, self._camera_information())], M.MAV_RESULT_ACCEPTED
            elif msg_id == M.MAVLINK_MSG_ID_VIDEO_STREAM_INFORMATION:
                streams = self._video_streams_information()
                wanted = int(p[1]) if math.isfinite(p[1]) else 0  # param2: stream id, 0 = all
                chosen = [m for m in streams if wanted in (0, m.stream_id)]
                result = M.MAV_RESULT_ACCEPTED if chosen else M.MAV_RESULT_DENIED
                extra = [Outgoing(CAMERA, m) for m in chosen]
            else:
                result = M.MAV_RESULT_DENIED
        ack = Outgoing(CAMERA, M.MAVLink_command_ack_message(cmd, result, 0, 0, *sender))
        return HandleResult([ack, *extra])

    def _camera_information(self) -> mavlink.MAVLink_message:
        c = self.camera
        assert c is not None
        focal_mm = 3.0
        sensor_h_mm = 2 * focal_mm * math.tan(math.radians(c.hfov_deg) / 2)
        sensor_v_mm = sensor_h_mm * c.height_px / c.width_px
        flags = M.CAMERA_CAP_FLAGS_HAS_VIDEO_STREAM
        return M.MAVLink_camera_information_message(
            self.v.time_boot_ms, _bytes32("col-sitl"), _bytes32("downward-rgb"), 1, focal_mm,
            sensor_h_mm, sensor_v_mm, c.width_px, c.height_px, 0, flags, 0, b"",
        )

    def _video_streams_information(self) -> list[mavlink.MAVLink_message]:
        """Stream 1: the colf:// frame stream (the companion's); stream 2, when sent: H.264 over
        RTP/UDP for ground stations."""
        c = self.camera
        assert c is not None
        count = 2 if c.rtp_uri else 1
        running = M.VIDEO_STREAM_STATUS_FLAGS_RUNNING
        streams = [M.MAVLink_video_stream_information_message(
            1, count, M.VIDEO_STREAM_TYPE_TCP_MPEG, running, c.framerate_hz,
            c.width_px, c.height_px, 0, 0, int(round(c.hfov_deg)), b"downward", c.uri.encode(),
        )]
        if c.rtp_uri:
            streams.append(M.MAVLink_video_stream_information_message(
                2, count, M.VIDEO_STREAM_TYPE_RTPUDP, running, c.framerate_hz, c.width_px, c.height_px, 0, 0,
                int(round(c.hfov_deg)), b"downward-h264", c.rtp_uri.encode(), M.VIDEO_STREAM_ENCODING_H264))
        return streams


def _param_name(raw: str | bytes) -> str:
    if isinstance(raw, bytes):
        raw = raw.decode("ascii", errors="replace")
    return raw.rstrip("\x00")


def _bytes32(text: str) -> list[int]:
    data = text.encode()[:32]
    return list(data) + [0] * (32 - len(data))
