"""The SITL process: a simulated vehicle behind MAVLink, camera and control-surface sockets.

One thread, one selector. The frame loop: advance one agent period (``steps_per_frame`` FDM
steps), send the frame's camera image and telemetry, end with the SYSTEM_TIME marker; in
lockstep wait for the answer (a setpoint echoing the marker's time_boot_ms, a MANUAL_CONTROL,
or an episode reset) or the timeout. Until some client answers, a lockstep SITL paces itself in
real time so that ground stations and MAVSDK can connect; after three unanswered frames it
falls back to that pacing (sitl/clock.py). The sockets are sitl/transports.py's, the camera
sitl/camera_feed.py's; what stays here is the frame loop and the MAVLink routing.
"""

from __future__ import annotations

import logging
import selectors
import socket
import threading
import time
from collections.abc import Callable
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

from sitl.camera_feed import CameraFeed, FrameSink
from sitl.clock import ClockStats, Pacer, frame_steps
from sitl.config import SitlConfig
from sitl.control_surface import RequestError, handle_request, parse_request
from sitl.exposure import authorised, check_exposure
from sitl.handler import AUTOPILOT, CAMERA, CameraInfo, MessageHandler, Outgoing
from sitl.personality import make_vehicle
from sitl.signing import SitlSigning
from sitl.telemetry import COMPOSERS, TelemetryScheduler
from sitl.transports import ControlChannel, ControlClient, MavClient, TcpClient, UdpClient, listener
from sitl.vehicle import FIRST_LOCKSTEP_EPISODE_S, SimVehicle

log = logging.getLogger("sitl.server")
M = mavlink
FORWARDED = ("MANUAL_CONTROL", "STATUSTEXT")


class SitlServer:
    """Runs a SimVehicle behind MAVLink, camera and control-surface sockets, frame by frame:
    the composition of the transports (sitl/transports.py), the clock (sitl/clock.py) and the
    camera (sitl/camera_feed.py), with the MAVLink routing between them and the vehicle."""

    def __init__(self, cfg: SitlConfig, frame_sink: FrameSink | None = None, signing_key: bytes | None = None,
                 allow_remote: bool = False, control_token: str | None = None) -> None:
        """``frame_sink``: where camera frames go instead of the TCP stream (a reader in this process);
        ``signing_key``: MAVLink 2 signing required with this key (sitl/signing.py); a host other
        than loopback needs ``allow_remote`` and a ``control_token`` (sitl/exposure.py)."""
        check_exposure(cfg.network.host, allow_remote, control_token)
        self.control_token = control_token
        self.cfg = cfg
        self.signing = SitlSigning(signing_key, cfg.network.system_id)
        self._frame_sink = frame_sink
        net = cfg.network
        self.vehicle: SimVehicle = make_vehicle(cfg)
        self.scheduler = TelemetryScheduler(self.vehicle.default_rates_hz)
        self.lockstep = cfg.clock.mode == "lockstep"
        self.steps_per_frame = frame_steps(cfg)
        self.sel = selectors.DefaultSelector()
        self.clients: list[MavClient] = []
        self.stats = ClockStats()
        self._stop = threading.Event()
        # stop() (a SIGTERM handler) must end a select() that waits for a lockstep answer:
        # Python retries an interrupted select() for its whole timeout (PEP 475), which with
        # lockstep_timeout_s = 10 outlived start_sitl's 5 s grace and got the SITL killed.
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._wake_w.setblocking(False)
        self.pacer = Pacer(cfg.clock.speed if not self.lockstep else 1.0)
        self._answered = False
        self._frame_ms = -1
        self._at_frame_boundary = True
        self._mav_out = {c: self.signing.attach(M.MAVLink(None, net.system_id, c)) for c in (AUTOPILOT, CAMERA)}
        for local, remote in zip(net.udp_local_ports, net.udp_remote_ports):
            c = UdpClient(net.host, local, remote)
            c.use_signing(self.signing)
            self.clients.append(c)
            self.sel.register(c.sock, selectors.EVENT_READ, lambda c=c: self._on_mavlink(c, c.read()))
        self.tcp_listener = listener(net.host, net.tcp_port) if net.tcp_port is not None else None
        if self.tcp_listener is not None:
            self.sel.register(self.tcp_listener, selectors.EVENT_READ, self._accept_tcp)
        self.control_listener = listener(net.host, net.control_port)
        self.control = ControlChannel(self.sel, self.control_listener, self._on_control_data)
        self.sel.register(self._wake_r, selectors.EVENT_READ, self._drain_wake)
        self.camera = self._open_camera() if cfg.camera.enabled else None
        cam_info = None
        if self.camera is not None:
            rtp = self.camera.rtp
            cam_info = CameraInfo(self.camera.server.uri, cfg.camera.width_px, cfg.camera.height_px, cfg.camera.hfov_deg,
                                  cfg.clock.frame_rate_hz, rtp.uri if rtp is not None else None)
        self.handler = MessageHandler(self.vehicle, self.scheduler, cam_info)
        self._rebooted = False  # the autopilot was silent for a reboot: its streams start afresh
        self._ran_free = False  # lockstep frames ran before anyone answered them (in real time)

    def _open_camera(self) -> CameraFeed:
        return CameraFeed(self.cfg, self.vehicle, self._frame_sink)

    # ----- addresses -------------------------------------------------------------------------
    def ports(self) -> dict[str, object]:
        """The ports actually bound (0 in the config means 'any free port')."""
        return {
            "udp": [[c.local_port, c.remote[1]] for c in self.clients if isinstance(c, UdpClient)],
            "tcp": self.tcp_listener.getsockname()[1] if self.tcp_listener else None,
            "control": self.control_listener.getsockname()[1],
            "camera": self.camera.server.port if self.camera else None,
            "camera_uri": self.camera.server.uri if self.camera else None,
            "rtp_video": self.cfg.network.rtp_video or None,
            "clock": self.cfg.clock.mode,
        }

    # ----- running ---------------------------------------------------------------------------
    def stop(self) -> None:
        self._stop.set()
        try:
            self._wake_w.send(b"\0")
        except OSError:
            pass  # already closed, or a wake-up is already pending

    def _drain_wake(self) -> None:
        try:
            self._wake_r.recv(64)
        except OSError:
            pass

    def serve(self, max_sim_s: float | None = None, on_frame: Callable[[], None] | None = None) -> None:
        """Run frames until stop() (or ``max_sim_s`` of simulation time), then close everything."""
        try:
            self.pacer.restart(self.vehicle.time_s)
            while not self._stop.is_set():
                if max_sim_s is not None and self.vehicle.time_s >= max_sim_s:
                    break
                self._run_frame()
                if on_frame is not None:
                    on_frame()
        finally:
            self.close()

    def _strict(self) -> bool:
        return self.lockstep and self.stats.attached

    def _run_frame(self) -> None:
        v = self.vehicle
        self._serve_control_queue()
        self._at_frame_boundary = False
        strict = self._strict()
        for _ in range(self.steps_per_frame):
            v.step()
            if not strict:
                self._send_due()
                if self.camera is not None and not self.lockstep:
                    self.camera.publish_if_due(blocking=False)
                self._pace()
        if strict:
            self._send_due()
        self._end_frame()
        if self.lockstep:
            self._await_answer()

    def _pace(self) -> None:
        """Real time: poll sockets until the wall clock catches up with simulation time."""
        target = self.pacer.target(self.vehicle.time_s)
        while True:
            self._poll(max(0.0, target - time.monotonic()))
            if time.monotonic() >= target or self._stop.is_set():
                return

    def _await_answer(self) -> None:
        self._at_frame_boundary = True
        timeout_s = self.cfg.clock.lockstep_timeout_s if self.stats.attached else 0.0
        deadline = time.monotonic() + timeout_s
        while not self._answered and not self._stop.is_set():
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                break
            self._poll(remaining)
        if not self.stats.attached:
            self._ran_free = True
            return
        if self.stats.frame_ended(self._answered):
            log.info("lockstep client silent: pacing in real time until it answers")
            self.pacer.restart(self.vehicle.time_s)

    def _end_frame(self) -> None:
        """Camera image (lockstep: the frame's own), pending events and the frame marker."""
        v = self.vehicle
        self.stats.frames += 1
        self._answered = False
        self._frame_ms = v.time_boot_ms
        if self.camera is not None:
            if self.lockstep:  # every frame's own image, fully written before its marker
                self.camera.publish(blocking=True)
            hb = self.camera.heartbeat(v.time_s)
            if hb is not None:
                self._broadcast(Outgoing(CAMERA, hb))
        if not self._silent_for_reboot():
            self._flush_events()
            self._greet_silent_udp_peers()
        if v.sends_frame_marker:
            self._broadcast(Outgoing(AUTOPILOT, COMPOSERS[M.MAVLINK_MSG_ID_SYSTEM_TIME](v)))
        self._flush_all()

    def _greet_silent_udp_peers(self) -> None:
        """A HEARTBEAT every frame to UDP remotes that have not talked yet: a companion that
        binds its port just after the SITL started (start_sitl, then udpin) missed the first
        1 Hz HEARTBEAT and waited up to 1 s to connect. Stops once the peer talks."""
        silent = [c for c in self.clients if isinstance(c, UdpClient) and not c.active]
        if silent:
            data = self._pack(Outgoing(AUTOPILOT, COMPOSERS[M.MAVLINK_MSG_ID_HEARTBEAT](self.vehicle)))
            for c in silent:
                c.send(data)

    def _flush_all(self) -> None:
        for c in self.clients:
            c.flush()

    def _silent_for_reboot(self) -> bool:
        """A rebooting autopilot sends and reads nothing, and comes back with its boot-time
        streams only (a companion asks for its streams again, as after connecting)."""
        if self.vehicle.rebooting():
            self._rebooted = True
            return True
        if self._rebooted:
            self._rebooted = False
            self.scheduler = TelemetryScheduler(self.vehicle.default_rates_hz)
            self.handler.scheduler = self.scheduler
        return False

    def _send_due(self) -> None:
        if self._silent_for_reboot():
            return
        v = self.vehicle
        for msg_id in self.scheduler.due(v.time_s):
            self._broadcast(Outgoing(AUTOPILOT, COMPOSERS[msg_id](v)))
        self._flush_events()
        if not self._strict():
            self._flush_all()

    def _flush_events(self) -> None:
        events = self.vehicle.events
        while events:
            severity, text = events.popleft()
            log.info("%s", text)
            self._broadcast(Outgoing(AUTOPILOT, M.MAVLink_statustext_message(severity, text.encode()[:50])))

    # ----- sending ---------------------------------------------------------------------------
    def _pack(self, out: Outgoing) -> bytes:
        return out.message.pack(self._mav_out[out.component])

    def _broadcast(self, out: Outgoing) -> None:
        data = self._pack(out)
        for c in self.clients:
            c.send(data)

    # ----- receiving -------------------------------------------------------------------------
    def _poll(self, timeout_s: float) -> None:
        for key, _ in self.sel.select(timeout_s):
            key.data()
        if any(isinstance(c, TcpClient) and c.closed for c in self.clients):
            self._drop_closed_tcp()

    def _drop_closed_tcp(self) -> None:
        for c in [c for c in self.clients if isinstance(c, TcpClient) and c.closed]:
            try:
                self.sel.unregister(c.sock)
            except (KeyError, ValueError):
                pass
            c.close()
            self.clients.remove(c)
            log.info("%s disconnected", c.name)

    def _on_mavlink(self, client: MavClient, msgs: list[mavlink.MAVLink_message]) -> None:
        for msg in msgs:
            if msg.get_type() == "SETUP_SIGNING":
                self.signing.on_setup_signing(msg, client.secure)
                continue
            if self._silent_for_reboot():
                self._forward(client, msg)
                continue
            result = self.handler.handle(msg)
            for out in result.replies:
                data = self._pack(out)
                if out.to_sender_only:
                    client.send(data)
                else:
                    for c in self.clients:
                        c.send(data)
            self._forward(client, msg)
            echo = result.lockstep_answer_ms
            if echo is not None and (echo == -1 or echo >= self._frame_ms):
                self._answered = True
                if self.lockstep and not self.stats.attached:
                    self.stats.attach()
        self._flush_events()
        self._flush_all()

    def _forward(self, source: MavClient, msg: mavlink.MAVLink_message) -> None:
        """Like PX4 with forwarding on: what one peer says reaches the other active peers (a
        ground station's joystick, and a companion's STATUSTEXT, e.g. its request for help)."""
        if msg.get_type() not in FORWARDED:
            return
        data = msg.get_msgbuf()
        for c in self.clients:
            if c is not source and c.active:
                c.send(bytes(data))

    def _accept_tcp(self) -> None:
        assert self.tcp_listener is not None
        try:
            sock, addr = self.tcp_listener.accept()
        except OSError:
            return
        c = TcpClient(sock, addr)
        c.use_signing(self.signing)
        self.clients.append(c)
        self.sel.register(sock, selectors.EVENT_READ, lambda c=c: self._on_mavlink(c, c.read()))
        log.info("%s connected", c.name)

    # ----- control surface -------------------------------------------------------------------
    def _on_control_data(self) -> None:
        if self._at_frame_boundary:
            self._serve_control_queue()

    def _serve_control_queue(self) -> None:
        """Answer queued control requests. Called only between frames, so an episode reset
        never lands in the middle of one: the first frame of an episode is always whole."""
        while (request := self.control.next_request()) is not None:
            self._reply_control(*request)

    def _reply_control(self, cc: ControlClient, line: bytes) -> None:
        if authorised(line, self.control_token):
            reply = self.control_reply(line)
        else:
            reply = {"ok": False, "error": "unauthorised: this control surface needs its \"token\""}
        self.control.reply(cc, reply)
        self._flush_events()
        self._flush_all()

    def _first_episode_start_s(self) -> float | None:
        """Where a reset's episode starts if it is a lockstep run's first, before anyone drove
        the clock (it ran in real time until now): :data:`FIRST_LOCKSTEP_EPISODE_S`. None: at
        the next whole second, as always (real time; an in-process SITL, driven from its first
        frame; any later episode)."""
        if self.lockstep and self._ran_free and self.vehicle.episode == 0:
            return FIRST_LOCKSTEP_EPISODE_S
        return None

    def control_reply(self, line: bytes) -> dict[str, Any]:
        """The reply to one control-surface request line, applied between frames (also the
        entry of an in-process client, which has no socket to send it over)."""
        camera_uri = self.camera.server.uri if self.camera else None
        try:
            req = parse_request(line)
            offset_ms = self.vehicle.clock_offset_ms
            reply = handle_request(self.vehicle, req, camera_uri, self.cfg.clock.mode,
                                   episode_start_s=self._first_episode_start_s())
            if req["cmd"] == "reset":
                if self.camera is not None:
                    self.camera.rebase_clock((self.vehicle.clock_offset_ms - offset_ms) / 1000.0)
                self.scheduler = self._fresh_scheduler()
                self.handler.scheduler = self.scheduler
                self._answered = True  # a reset answers the frame: the next one shows the start
                if self.lockstep and not self.stats.attached:
                    # whoever resets episodes drives the clock: from the first frame of the
                    # episode on, each frame waits for its answer (no real-time frames slip in)
                    self.stats.attach()
        except RequestError as exc:
            reply = {"ok": False, "error": str(exc)}
        except (RecursionError, ValueError, TypeError, OverflowError, KeyError) as exc:
            # what the checks missed (JSON nested too deep, ...) is refused; it never ends the run
            log.warning("control request refused: %r", exc)
            reply = {"ok": False, "error": f"bad request ({type(exc).__name__}): {exc}"}
        return reply

    def _fresh_scheduler(self) -> TelemetryScheduler:
        """Keep requested intervals but restart the phase, so an episode is independent of the last."""
        return self.scheduler.restarted(self.vehicle.default_rates_hz, self.vehicle.time_s)

    # ----- teardown --------------------------------------------------------------------------
    def close(self) -> None:
        for c in list(self.clients):
            try:
                c.close()
            except OSError:
                pass
        for s in (self.tcp_listener, self.control_listener, self._wake_r, self._wake_w):
            if s is not None:
                s.close()
        if self.camera is not None:
            self.camera.close()
        self.sel.close()
