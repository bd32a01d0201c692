"""Several clients of one SITL at once: a ground station on TCP, an offboard client on UDP and
the control surface; clients that misbehave or vanish do not disturb the others."""

from __future__ import annotations

import json
import socket
import struct
import threading
import time
from collections.abc import Iterator

import pytest
from pymavlink.dialects.v20 import common as M

from companion.errors import SimulatorError
from companion.simulator import SimulatorClient, SitlProcess, start_sitl
from tests.mav_client import MavTestClient

pytestmark = [pytest.mark.realtime, pytest.mark.e2e]

SPEED = 2.0
GCS_SYSTEM, GCS_COMPONENT = 255, 190  # as QGroundControl
OFFBOARD_SYSTEM, OFFBOARD_COMPONENT = 245, 191
NOMINAL_POSITION_HZ = 30.0 * SPEED  # LOCAL_POSITION_NED's default rate, in wall time


class TcpGroundStation(MavTestClient):
    """The same test client over a MAVLink TCP connection, as a ground station connects."""

    def __init__(self, port: int) -> None:
        super().__init__()
        self.sock.close()
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=2.0)
        self.mav = M.MAVLink(None, GCS_SYSTEM, GCS_COMPONENT)
        self.closed = False

    def pump(self, timeout_s: float = 0.2) -> list[M.MAVLink_message]:
        out: list[M.MAVLink_message] = []
        self.sock.settimeout(timeout_s)
        while not self.closed:
            try:
                data = self.sock.recv(65536)
            except (TimeoutError, BlockingIOError):
                return out
            if not data:
                self.closed = True
                break
            for msg in self.parser.parse_buffer(data) or []:
                if msg.get_type() == "BAD_DATA":
                    continue
                self.latest[msg.get_type()] = msg
                out.append(msg)
                self.inbox.append(msg)
            self.sock.settimeout(0.0)
        return out

    def send(self, msg: M.MAVLink_message) -> None:
        self.sock.sendall(msg.pack(self.mav))

    def send_raw(self, data: bytes) -> None:
        self.sock.sendall(data)


@pytest.fixture
def sitl() -> Iterator[tuple[SitlProcess, MavTestClient]]:
    """A real-time SITL with its MAVLink TCP server on, and the UDP offboard client it sends to."""
    offboard = MavTestClient()
    offboard.mav = M.MAVLink(None, OFFBOARD_SYSTEM, OFFBOARD_COMPONENT)
    proc = start_sitl(offboard.port, clock="realtime", camera=False, extra_args=["--tcp", "0", "--speed", str(SPEED)])
    try:
        yield proc, offboard
    finally:
        proc.stop()
        offboard.close()


@pytest.fixture
def gcs(sitl: tuple[SitlProcess, MavTestClient]) -> Iterator[TcpGroundStation]:
    port = sitl[0].ports["tcp"]
    assert isinstance(port, int) and port > 0, "--tcp 0 must open the MAVLink TCP server on a free port"
    station = TcpGroundStation(port)
    yield station
    station.close()


def autopilot_heartbeat(m: M.MAVLink_message) -> bool:
    return m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 1


def ack_of(cmd: int):  # noqa: ANN201 - a predicate
    return lambda m: m.get_type() == "COMMAND_ACK" and m.command == cmd


def position_rate_hz(client: MavTestClient, wall_s: float) -> float:
    """LOCAL_POSITION_NED messages per wall second that reach ``client``."""
    end, count = time.monotonic() + wall_s, 0
    while time.monotonic() < end:
        count += sum(m.get_type() == "LOCAL_POSITION_NED" for m in client.pump(0.05))
    return count / wall_s


def hello(client: MavTestClient) -> None:
    """Talk once, as every real client does: the SITL then knows the peer is there."""
    client.send(M.MAVLink_heartbeat_message(M.MAV_TYPE_ONBOARD_CONTROLLER, M.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3))


def test_both_clients_get_telemetry_and_each_gets_its_own_acks(sitl, gcs: TcpGroundStation) -> None:
    _, offboard = sitl
    for client in (gcs, offboard):
        client.wait_for(autopilot_heartbeat, 5.0)
        client.wait_for(lambda m: m.get_type() == "LOCAL_POSITION_NED", 5.0)
    hello(offboard)
    gcs.send(M.MAVLink_command_long_message(1, 1, 31998, 0, 0, 0, 0, 0, 0, 0, 0))
    ack = gcs.wait_for(ack_of(31998), 5.0)
    assert ack.result == M.MAV_RESULT_UNSUPPORTED
    assert (ack.target_system, ack.target_component) == (GCS_SYSTEM, GCS_COMPONENT)
    offboard.pump(0.3)
    assert not any(m.get_type() == "COMMAND_ACK" for m in offboard.inbox), "the GCS's ACK leaked to UDP"
    offboard.send(M.MAVLink_command_long_message(1, 1, 31999, 0, 0, 0, 0, 0, 0, 0, 0))
    ack = offboard.wait_for(ack_of(31999), 5.0)
    assert (ack.target_system, ack.target_component) == (OFFBOARD_SYSTEM, OFFBOARD_COMPONENT)
    gcs.pump(0.3)
    assert not any(m.get_type() == "COMMAND_ACK" for m in gcs.inbox), "the offboard client's ACK leaked to TCP"
    # one vehicle: arming from the ground station shows on both links
    assert gcs.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
    for client in (gcs, offboard):
        client.wait_for(lambda m: autopilot_heartbeat(m) and m.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED, 5.0)
    assert offboard.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 0) == M.MAV_RESULT_ACCEPTED
    gcs.wait_for(lambda m: autopilot_heartbeat(m) and not m.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED, 5.0)


def test_manual_control_from_the_ground_station_is_forwarded_to_the_offboard_client(
    sitl, gcs: TcpGroundStation
) -> None:
    _, offboard = sitl
    offboard.wait_for(autopilot_heartbeat, 5.0)
    gcs.wait_for(autopilot_heartbeat, 5.0)
    hello(offboard)
    sticks = M.MAVLink_manual_control_message(1, 250, -300, 500, 100, 0b1)
    deadline = time.monotonic() + 5.0
    got = None
    while got is None and time.monotonic() < deadline:  # as a ground station streams its joystick
        gcs.send(sticks)
        got = next((m for m in offboard.pump(0.05) if m.get_type() == "MANUAL_CONTROL"), None)
    assert got is not None, "MANUAL_CONTROL from the TCP ground station never reached the UDP client"
    assert (got.x, got.y, got.z, got.r, got.buttons) == (250, -300, 500, 100, 1)
    assert (got.get_srcSystem(), got.get_srcComponent()) == (GCS_SYSTEM, GCS_COMPONENT)
    gcs.pump(0.3)
    assert not any(m.get_type() == "MANUAL_CONTROL" for m in gcs.inbox), "echoed back to its sender"


def test_statustext_from_the_companion_reaches_the_ground_station(sitl, gcs: TcpGroundStation) -> None:
    """A companion's request for help (STATUSTEXT) is forwarded as PX4 forwards it."""
    _, offboard = sitl
    offboard.wait_for(autopilot_heartbeat, 5.0)
    gcs.wait_for(autopilot_heartbeat, 5.0)
    hello(offboard)
    text = M.MAVLink_statustext_message(M.MAV_SEVERITY_WARNING, b"COL: unsure, holding - take over (1)")
    offboard.send(text)
    got = gcs.wait_for(lambda m: m.get_type() == "STATUSTEXT" and m.text.startswith("COL:"), 5.0)
    assert got is not None and got.text == "COL: unsure, holding - take over (1)"
    assert got.severity == M.MAV_SEVERITY_WARNING
    assert (got.get_srcSystem(), got.get_srcComponent()) == (OFFBOARD_SYSTEM, OFFBOARD_COMPONENT)


def test_a_tcp_client_that_vanishes_mid_stream_does_not_disturb_the_others(sitl, gcs: TcpGroundStation) -> None:
    proc, offboard = sitl
    offboard.wait_for(autopilot_heartbeat, 5.0)
    gcs.wait_for(autopilot_heartbeat, 5.0)
    for linger in (True, False):  # a reset connection, then one closed mid-packet
        rude = TcpGroundStation(int(proc.ports["tcp"]))
        rude.wait_for(lambda m: m.get_type() == "LOCAL_POSITION_NED", 5.0)
        packet = M.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3).pack(rude.mav)
        rude.send_raw(packet[: len(packet) // 2])
        if linger:
            rude.sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        rude.sock.close()
    offboard.pump(0.05)  # what queued up meanwhile
    assert position_rate_hz(offboard, 1.0) > 0.7 * NOMINAL_POSITION_HZ
    gcs.pump(0.05)
    assert position_rate_hz(gcs, 0.5) > 0.7 * NOMINAL_POSITION_HZ
    assert gcs.command(31998) == M.MAV_RESULT_UNSUPPORTED
    assert proc.proc.poll() is None


def _raw_request(sock: socket.socket, reader, line: bytes) -> dict:  # noqa: ANN001
    sock.sendall(line + b"\n")
    reply = reader.readline()
    assert reply, f"the control surface closed the connection on {line[:40]!r}"
    return json.loads(reply)


BAD_REQUESTS = [
    b"{not json", b'"a string"', b"[1, 2]", b'{"cmd": 5}', b"\xff\xfe\xfd", b'{"cmd": "fly_to_the_moon"}',
    b'{"cmd": "reset", "seed": "seven"}', b'{"cmd": "reset", "seed": -1}',
    b'{"cmd": "set_ground_vehicle", "velocity_ne_m_s": [1]}',
    b'{"cmd": "set_ground_vehicle", "velocity_ne_m_s": [NaN, 0]}',
    b'{"cmd": "set_ground_vehicle", "velocity_ne_m_s": [1e400, 0]}',
    b"[" * 5000,  # nested too deep for the JSON decoder: it once ended the SITL
]


def test_the_control_surface_refuses_malformed_requests_and_keeps_working(sitl) -> None:
    proc, _ = sitl
    with socket.create_connection(("127.0.0.1", proc.control_port), timeout=5.0) as sock:
        reader = sock.makefile("rb")
        for line in BAD_REQUESTS:
            reply = _raw_request(sock, reader, line)
            assert reply["ok"] is False and reply["error"], line[:40]
            assert _raw_request(sock, reader, b'{"cmd": "info"}')["ok"] is True  # the connection goes on
        assert _raw_request(sock, reader, b'{"cmd": "truth"}')["episode"] == 0  # nothing was applied
    assert proc.proc.poll() is None


def test_a_control_client_that_never_reads_its_replies_does_not_stall_the_simulation(sitl) -> None:
    proc, offboard = sitl
    offboard.wait_for(autopilot_heartbeat, 5.0)
    hog = socket.create_connection(("127.0.0.1", proc.control_port), timeout=5.0)

    def flood() -> None:  # tens of MB of replies that nobody reads
        try:
            for _ in range(40):
                hog.sendall(b'{"cmd": "info"}\n' * 1000)
        except OSError:
            pass  # the SITL gave up on us: what we want

    writer = threading.Thread(target=flood, daemon=True)
    writer.start()
    time.sleep(0.5)
    ctl = SimulatorClient("127.0.0.1", proc.control_port, timeout_s=5.0)
    try:
        t0 = ctl.truth()["time_boot_ms"]
        assert position_rate_hz(offboard, 2.0) > 0.3 * NOMINAL_POSITION_HZ  # a hiccup at most
        assert ctl.truth()["time_boot_ms"] - t0 > 1000  # simulation time went on
    finally:
        ctl.close()
        hog.close()
        writer.join(5.0)
    assert proc.proc.poll() is None


def test_set_ground_vehicle_moves_the_pad_in_truth(sitl) -> None:
    proc, _ = sitl
    ctl = SimulatorClient("127.0.0.1", proc.control_port)
    try:
        still = ctl.truth()
        assert still["pad_ned"][:2] == [0.0, 0.0]
        assert ctl.request("set_ground_vehicle", velocity_ne_m_s=[1.0, -0.5])["ok"] is True
        start = ctl.truth()
        time.sleep(0.5)
        moved = ctl.truth()
        dt_s = (moved["time_boot_ms"] - start["time_boot_ms"]) / 1000.0
        assert dt_s > 0.5
        assert moved["pad_ned"][0] - start["pad_ned"][0] == pytest.approx(1.0 * dt_s, abs=2e-3)
        assert moved["pad_ned"][1] - start["pad_ned"][1] == pytest.approx(-0.5 * dt_s, abs=2e-3)
        assert moved["pad_ned"][2] == still["pad_ned"][2]  # the roof keeps its height
        ctl.request("set_ground_vehicle", velocity_ne_m_s=[0.0, 0.0])
        parked = ctl.truth()
        time.sleep(0.2)
        assert ctl.truth()["pad_ned"] == parked["pad_ned"]
        with pytest.raises(SimulatorError, match="velocity_ne_m_s"):
            ctl.request("set_ground_vehicle", velocity_ne_m_s=[100.0, 0.0])
    finally:
        ctl.close()


def test_a_parameter_change_is_told_to_every_client(sitl, gcs: TcpGroundStation) -> None:
    _, offboard = sitl
    for client in (gcs, offboard):
        client.wait_for(autopilot_heartbeat, 5.0)
        hello(client)
    offboard.send(M.MAVLink_param_set_message(1, 1, b"MPC_LAND_SPEED", 0.9, M.MAV_PARAM_TYPE_REAL32))
    for client in (offboard, gcs):
        pv = client.wait_for(lambda m: m.get_type() == "PARAM_VALUE" and m.param_id == "MPC_LAND_SPEED", 5.0)
        assert pv.param_value == pytest.approx(0.9)
