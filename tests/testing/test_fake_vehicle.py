"""The fake vehicle itself, driven by a bare pymavlink codec on a plain UDP socket."""

from __future__ import annotations

import math
import socket
import time
from collections.abc import Iterator

import pytest
from pymavlink.dialects.v20 import common as mavlink

import companion.link.px4_modes as px4_modes
from companion.testing import FakeVehicle


class Client:
    """A minimal MAVLink peer: one socket, one codec, no threads."""

    def __init__(self, fake: FakeVehicle) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.05)
        self.target = fake.address
        self.mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=191)
        self.parser = mavlink.MAVLink(None)

    def send(self, msg) -> None:
        self.sock.sendto(msg.pack(self.mav), self.target)
        self.mav.seq = (self.mav.seq + 1) % 256

    def hello(self) -> None:
        self.send(self.mav.heartbeat_encode(18, 8, 0, 0, 4))

    def receive(self, kind: str, timeout_s: float = 1.0, predicate=None):
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            try:
                data, _ = self.sock.recvfrom(65535)
            except TimeoutError:
                continue
            for msg in self.parser.parse_buffer(data) or []:
                if msg.get_type() == kind and (predicate is None or predicate(msg)):
                    return msg
        return None

    def command(self, command: int, *params: float):
        padded = (list(params) + [0.0] * 7)[:7]
        self.send(self.mav.command_long_encode(1, 1, command, 0, *padded))
        return self.receive("COMMAND_ACK", predicate=lambda m: m.command == command)

    def close(self) -> None:
        self.sock.close()


@pytest.fixture
def fake() -> Iterator[FakeVehicle]:
    with FakeVehicle(heartbeat_period_s=0.2) as vehicle:
        yield vehicle


@pytest.fixture
def client(fake: FakeVehicle) -> Iterator[Client]:
    peer = Client(fake)
    peer.hello()
    fake.wait_for("HEARTBEAT")  # it knows us now
    yield peer
    peer.close()


def test_binds_loopback_on_a_free_port_and_answers_whoever_talks(fake, client) -> None:
    host, port = fake.address
    assert host == "127.0.0.1" and port > 0
    assert fake.connection_string == f"udpout:127.0.0.1:{port}"
    beat = client.receive("HEARTBEAT")
    assert beat.autopilot == mavlink.MAV_AUTOPILOT_PX4 and beat.type == mavlink.MAV_TYPE_QUADROTOR
    assert px4_modes.decode(beat.custom_mode) == "AUTO.LOITER"
    assert client.receive("LOCAL_POSITION_NED") is not None
    assert client.receive("SYSTEM_TIME") is not None


def test_records_what_it_receives(fake, client) -> None:
    client.send(
        client.mav.set_position_target_local_ned_encode(
            77, 1, 1, 8, 0x5C7, 0, 0, 0, 1.0, 2.0, 3.0, 0, 0, 0, 0, 0.5
        )
    )
    msg = fake.wait_for("SET_POSITION_TARGET_LOCAL_NED")
    assert (msg.time_boot_ms, msg.coordinate_frame, msg.type_mask) == (77, 8, 0x5C7)
    assert (msg.vx, msg.vy, msg.vz, msg.yaw_rate) == (1.0, 2.0, 3.0, 0.5)
    assert len(fake.messages("HEARTBEAT")) == 1
    fake.clear_messages()
    assert fake.messages() == []
    with pytest.raises(TimeoutError):
        fake.wait_for("MANUAL_CONTROL", timeout_s=0.05)


def test_acks_commands_and_changes_mode(fake, client) -> None:
    ack = client.command(mavlink.MAV_CMD_DO_SET_MODE, 1, 6, 0)
    assert ack.result == mavlink.MAV_RESULT_ACCEPTED and fake.mode == "OFFBOARD"
    beat = client.receive("HEARTBEAT", predicate=lambda m: m.custom_mode == 6 << 16)
    assert beat is not None
    ack = client.command(mavlink.MAV_CMD_DO_SET_MODE, 1, 99, 0)
    assert ack.result == mavlink.MAV_RESULT_UNSUPPORTED
    assert client.command(12345).result == mavlink.MAV_RESULT_UNSUPPORTED


def test_arming_can_be_refused_and_commands_ignored(fake, client) -> None:
    fake.set_arm_result("TEMPORARILY_REJECTED")
    ack = client.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    assert ack.result == mavlink.MAV_RESULT_TEMPORARILY_REJECTED and not fake.armed
    fake.set_arm_result("ACCEPTED")
    assert client.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == 0 and fake.armed
    fake.set_ack_commands(False)
    assert client.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0) is None
    assert len(fake.commands(mavlink.MAV_CMD_COMPONENT_ARM_DISARM)) == 3


def test_records_message_interval_requests(fake, client) -> None:
    client.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 30, 20_000)
    assert fake.requested_intervals_us() == {30: 20_000.0}


def test_offboard_body_velocity_moves_it_along_its_heading(fake, client) -> None:
    fake.stream_rate_hz = 0.0
    client.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    fake.place(0.0, 0.0, -5.0, yaw_rad=math.pi / 2)  # facing east
    client.command(mavlink.MAV_CMD_DO_SET_MODE, 1, 6, 0)
    client.send(
        client.mav.set_position_target_local_ned_encode(
            0, 1, 1, 8, 0x5C7, 0, 0, 0, 1.0, 0.0, 0.0, 0, 0, 0, 0, 0.0
        )
    )
    fake.wait_for("SET_POSITION_TARGET_LOCAL_NED")
    for _ in range(10):
        fake.send_frame()
    north, east, down = fake.autopilot.state.position_ned_m
    assert east == pytest.approx(0.95, abs=1e-6) and abs(north) < 1e-6 and down == -5.0


def test_send_frame_ends_with_system_time_marker(fake, client) -> None:
    fake.stream_rate_hz = 0.0
    time.sleep(0.1)
    t = fake.send_frame(time_boot_ms=5000)
    assert t == 5000
    marker = client.receive("SYSTEM_TIME", predicate=lambda m: m.time_boot_ms == 5000)
    assert marker is not None
    assert fake.send_frame() == 5000 + fake.frame_period_ms


def test_goes_silent_and_comes_back(fake, client) -> None:
    assert client.receive("HEARTBEAT") is not None
    fake.go_silent()
    time.sleep(0.05)
    while client.receive("HEARTBEAT", timeout_s=0.05) is not None:
        pass  # drain what was already in flight
    assert client.receive("HEARTBEAT", timeout_s=0.5) is None
    client.send(client.mav.heartbeat_encode(18, 8, 0, 0, 4))
    time.sleep(0.1)
    assert len(fake.messages("HEARTBEAT")) == 1  # unheard while silent
    fake.resume()
    assert client.receive("HEARTBEAT", timeout_s=1.0) is not None


def test_sends_manual_control_as_a_ground_station(fake, client) -> None:
    fake.send_manual_control(x=100, y=-200, z=300, r=400, buttons=1, buttons2=2)
    msg = client.receive("MANUAL_CONTROL")
    assert (msg.x, msg.y, msg.z, msg.r, msg.buttons, msg.buttons2) == (100, -200, 300, 400, 1, 2)
    assert msg.get_srcSystem() == 255 and msg.target == 1


def test_survives_garbage_and_counts_it(fake, client, rng) -> None:
    for _ in range(20):
        client.sock.sendto(rng.integers(0, 256, 100, dtype="uint8").tobytes(), fake.address)
    client.sock.sendto(b"\xfd\x01\x00", fake.address)
    assert client.command(mavlink.MAV_CMD_DO_SET_MODE, 1, 4, 3).result == 0
    assert fake.bad_datagrams > 0


def test_close_stops_the_thread_and_frees_the_port() -> None:
    fake = FakeVehicle()
    host, port = fake.address
    fake.close()
    fake.close()
    assert not fake._thread.is_alive()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind((host, port))  # free again
