"""A scripted MAVLink vehicle on a real loopback UDP socket, for testing links and sessions.

It looks like PX4 from the outside (HEARTBEAT with PX4 custom modes, COMMAND_ACK, telemetry,
SYSTEM_TIME frame markers) and records everything it receives, so a test can assert on what
went over the wire. Knobs let a test refuse arming, ignore commands, go silent and come back,
inject MANUAL_CONTROL or garbage, and drive lockstep frames itself.

Example::

    with FakeVehicle() as fake:
        link = MavlinkLink(LinkConfig(connection=fake.connection_string))
        link.connect()
        ...
        fake.wait_for("SET_POSITION_TARGET_LOCAL_NED")
"""

from __future__ import annotations

import select
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

from companion.testing.fake_autopilot import FakeAutopilot, result_code

Address = tuple[str, int]


class _NullFile:
    """pymavlink encoders want a file; packets are sent by hand instead."""

    def write(self, _buf: bytes) -> None:
        return None


@dataclass(frozen=True)
class Received:
    """One message the fake vehicle received."""

    received_s: float  # monotonic
    address: Address
    msg: Any  # the decoded pymavlink message


class FakeVehicle:
    """A PX4-like MAVLink endpoint on 127.0.0.1 (a free port), running its own thread.

    ``stream_rate_hz`` > 0 streams telemetry in real time; 0 leaves the clock to the test,
    which then calls :meth:`send_frame` as the SITL's lockstep does. ``remote`` is an address
    it sends to unprompted (as PX4's SITL sends to 14540); otherwise it answers whoever talks.
    """

    def __init__(
        self,
        *,
        system_id: int = 1,
        component_id: int = 1,
        heartbeat: bool = True,
        heartbeat_period_s: float = 0.5,
        stream_rate_hz: float = 20.0,
        frame_period_ms: int = 95,
        arm_result: str | int = "ACCEPTED",
        ack_commands: bool = True,
        remote: Address | None = None,
    ) -> None:
        self._mav = mavlink.MAVLink(_NullFile(), srcSystem=system_id, srcComponent=component_id)
        self._gcs = mavlink.MAVLink(_NullFile(), srcSystem=255, srcComponent=190)
        self.autopilot = FakeAutopilot(self._mav, arm_result)
        self.autopilot.ack_commands = ack_commands
        self.system_id = system_id
        self.heartbeat_enabled = heartbeat
        self.heartbeat_period_s = heartbeat_period_s
        self.stream_rate_hz = stream_rate_hz
        self.frame_period_ms = frame_period_ms
        self.bad_datagrams = 0
        self._silent = False
        self._peers: list[Address] = [remote] if remote else []
        self._received: list[Received] = []
        self._lock = threading.RLock()
        self._arrived = threading.Condition(self._lock)
        self._stop = threading.Event()
        self._sim_ms = 0
        self._t0 = time.monotonic()
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._sock.bind(("127.0.0.1", 0))
        self._thread = threading.Thread(target=self._run, name="fake-vehicle", daemon=True)
        self._thread.start()

    # ----------------------------------------------------------------- identity
    @property
    def address(self) -> Address:
        host, port = self._sock.getsockname()
        return str(host), int(port)

    @property
    def connection_string(self) -> str:
        """What a link passes to reach this vehicle (it speaks first, as to a UDP server)."""
        host, port = self.address
        return f"udpout:{host}:{port}"

    # ----------------------------------------------------------------- knobs
    def set_arm_result(self, result: str | int) -> None:
        """Answer arming with this MAV_RESULT ("ACCEPTED", "DENIED", "TEMPORARILY_REJECTED")."""
        with self._lock:
            self.autopilot.arm_result = result_code(result)

    def set_ack_commands(self, ack: bool) -> None:
        with self._lock:
            self.autopilot.ack_commands = ack

    def drop_param_echoes(self, count: int) -> None:
        """Apply the next ``count`` PARAM_SETs without echoing them (replies lost on the way)."""
        with self._lock:
            self.autopilot.drop_param_echoes = count

    def go_silent(self) -> None:
        """Simulate a radio drop: send nothing and hear nothing until :meth:`resume`."""
        with self._lock:
            self._silent = True

    def resume(self) -> None:
        with self._lock:
            self._silent = False

    @property
    def silent(self) -> bool:
        return self._silent

    def place(self, north_m: float, east_m: float, down_m: float, yaw_rad: float = 0.0) -> None:
        """Put the vehicle at a pose, at rest (in the air when ``down_m`` < 0), as a SITL reset does."""
        with self._lock:
            state = self.autopilot.state
            state.position_ned_m = [north_m, east_m, min(down_m, 0.0)]
            state.velocity_ned_m_s = [0.0, 0.0, 0.0]
            state.yaw_rad = yaw_rad
            state.landed_state = "IN_AIR" if down_m < 0 else "ON_GROUND"

    @property
    def mode(self) -> str:
        """The fake autopilot's current PX4 mode name."""
        with self._lock:
            return self.autopilot.state.mode

    @property
    def armed(self) -> bool:
        with self._lock:
            return self.autopilot.state.armed

    # ----------------------------------------------------------------- injections
    def send_manual_control(
        self,
        x: int = 0,
        y: int = 0,
        z: int = 500,
        r: int = 0,
        buttons: int = 0,
        buttons2: int = 0,
        target: int | None = None,
    ) -> None:
        """Send MANUAL_CONTROL as a ground station (system 255) would; raw MAVLink units."""
        target = self.system_id if target is None else target
        msg = self._gcs.manual_control_encode(target, x, y, z, r, buttons, buttons2)
        self._send_all([msg], self._gcs)

    def send_frame(self, time_boot_ms: int | None = None) -> int:
        """One lockstep frame: advance the clock a frame, send telemetry, end with SYSTEM_TIME."""
        with self._lock:
            self._sim_ms = (
                self._sim_ms + self.frame_period_ms if time_boot_ms is None else time_boot_ms
            )
            self.autopilot.advance(self.frame_period_ms / 1000.0)
            msgs = self.autopilot.telemetry(self._sim_ms)
            msgs.append(self._mav.system_time_encode(int(time.time() * 1e6), self._sim_ms))
            self._send_all(msgs)
            return self._sim_ms

    def send_message(self, msg: Any) -> None:
        """Send any message encoded with :attr:`encoder` (the vehicle's identity)."""
        self._send_all([msg])

    @property
    def encoder(self) -> Any:
        return self._mav

    def send_garbage(self, data: bytes) -> None:
        """Send raw bytes to every peer (malformed-input tests)."""
        with self._lock:
            for peer in self._peers:
                self._sock.sendto(data, peer)

    # ----------------------------------------------------------------- records
    def messages(self, kind: str | None = None) -> list[Any]:
        """Messages received so far (of one type, or all), oldest first."""
        with self._lock:
            return [r.msg for r in self._received if kind is None or r.msg.get_type() == kind]

    def clear_messages(self) -> None:
        with self._lock:
            self._received.clear()

    def wait_for(
        self,
        kind: str,
        timeout_s: float = 2.0,
        predicate: Callable[[Any], bool] | None = None,
    ) -> Any:
        """The first received ``kind`` message (matching ``predicate``); TimeoutError if none."""
        deadline = time.monotonic() + timeout_s
        with self._arrived:
            while True:
                for r in self._received:
                    if r.msg.get_type() == kind and (predicate is None or predicate(r.msg)):
                        return r.msg
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    raise TimeoutError(f"fake vehicle received no {kind} within {timeout_s} s")
                self._arrived.wait(remaining)

    def requested_intervals_us(self) -> dict[int, float]:
        """Message id -> interval in microseconds, from MAV_CMD_SET_MESSAGE_INTERVAL received."""
        return {
            int(m.param1): float(m.param2)
            for m in self.messages("COMMAND_LONG")
            if m.command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL
        }

    def commands(self, command: int) -> list[Any]:
        return [m for m in self.messages("COMMAND_LONG") if m.command == command]

    # ----------------------------------------------------------------- lifecycle
    def close(self) -> None:
        """Stop the thread and release the port. Idempotent."""
        self._stop.set()
        if self._thread.is_alive() and threading.current_thread() is not self._thread:
            self._thread.join(timeout=2.0)
        self._sock.close()

    def __enter__(self) -> FakeVehicle:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ----------------------------------------------------------------- thread
    def _run(self) -> None:
        next_heartbeat = next_stream = next_slow = time.monotonic()
        while not self._stop.is_set():
            self._receive(0.01)
            now = time.monotonic()
            if now >= next_heartbeat:
                next_heartbeat = now + self.heartbeat_period_s
                if self.heartbeat_enabled:
                    self._send_all([self.autopilot.heartbeat()])
            if self.stream_rate_hz > 0 and now >= next_stream:
                next_stream = now + 1.0 / self.stream_rate_hz
                self._stream(1.0 / self.stream_rate_hz)
            if now >= next_slow:
                next_slow = now + 1.0
                self._send_all(self.autopilot.slow_telemetry())

    def _stream(self, dt_s: float) -> None:
        with self._lock:
            self.autopilot.advance(dt_s)
            self._sim_ms = int((time.monotonic() - self._t0) * 1000)
            msgs = self.autopilot.telemetry(self._sim_ms)
            msgs.append(self._mav.system_time_encode(int(time.time() * 1e6), self._sim_ms))
            self._send_all(msgs)  # the SITL ends every frame with SYSTEM_TIME in real time too

    def _receive(self, timeout_s: float) -> None:
        try:
            ready, _, _ = select.select([self._sock], [], [], timeout_s)
            while ready:
                data, address = self._sock.recvfrom(65535)
                self._datagram(data, address)
                ready, _, _ = select.select([self._sock], [], [], 0)
        except OSError:
            return

    def _datagram(self, data: bytes, address: Address) -> None:
        with self._lock:
            if self._silent:
                return
            if address not in self._peers:
                self._peers.append(address)
                if self.heartbeat_enabled:  # greet at once, so a test need not wait a period
                    self._send_all([self.autopilot.heartbeat()])
            parser = mavlink.MAVLink(_NullFile())  # one per datagram: a torn packet stays in it
            parser.robust_parsing = True
            try:
                msgs = parser.parse_buffer(data) or []
            except Exception:  # noqa: BLE001 - a fake must survive whatever it is sent
                self.bad_datagrams += 1
                return
            for msg in msgs:
                if msg.get_type() == "BAD_DATA":
                    self.bad_datagrams += 1
                    continue
                self._received.append(Received(time.monotonic(), address, msg))
                self._send_all(self.autopilot.handle(msg))
                if msg.get_type() in ("COMMAND_LONG", "COMMAND_INT") and self.heartbeat_enabled:
                    self._send_all([self.autopilot.heartbeat()])  # show the new state promptly
            self._arrived.notify_all()

    def _send_all(self, msgs: list[Any], encoder: Any | None = None) -> None:
        encoder = encoder or self._mav
        with self._lock:
            if self._silent or self._sock.fileno() < 0:
                return
            for msg in msgs:
                buf = msg.pack(encoder)
                encoder.seq = (encoder.seq + 1) % 256
                for peer in self._peers:
                    try:
                        self._sock.sendto(buf, peer)
                    except OSError:
                        continue
