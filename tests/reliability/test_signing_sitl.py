"""MAVLink 2 signing at the SITL: signed clients fly; unsigned, wrongly signed and replayed
commands and setpoints have no effect; heartbeats still flow; SETUP_SIGNING over a wire."""

from __future__ import annotations

import secrets
import socket
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as M

from colcommon.signing import make_signing
from companion.simulator import SitlProcess, start_sitl
from tests.mav_client import MavTestClient, nan7

pytestmark = [pytest.mark.realtime, pytest.mark.e2e]

KEY = bytes(range(1, 33))
OFFBOARD = 6 << 16


def signed_client(key: bytes | None, link_id: int = 7) -> MavTestClient:
    c = MavTestClient()
    if key is not None:
        c.mav.signing = make_signing(key, link_id)
        c.parser.signing = make_signing(key, link_id)
    return c


class Intruder:
    """Sends to the SITL's UDP port from its own socket, without (or with a wrong) key."""

    def __init__(self, sitl_addr: tuple[str, int], key: bytes | None = None) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.addr = sitl_addr
        self.mav = M.MAVLink(None, 245, 191)
        if key is not None:
            self.mav.signing = make_signing(key, 9)

    def send(self, msg: M.MAVLink_message) -> None:
        self.sock.sendto(msg.pack(self.mav), self.addr)

    def send_raw(self, data: bytes) -> None:
        self.sock.sendto(data, self.addr)

    def close(self) -> None:
        self.sock.close()


@pytest.fixture
def key_file(tmp_path: Path) -> Path:
    p = tmp_path / "signing.key"
    p.write_text(KEY.hex() + "\n")
    return p


@pytest.fixture
def signed_sitl(key_file: Path) -> Iterator[tuple[SitlProcess, MavTestClient]]:
    client = signed_client(KEY)
    sitl = start_sitl(client.port, clock="realtime", camera=False,
                      extra_args=["--speed", "4", "--signing-key", str(key_file), "--tcp", "0"])
    try:
        client.wait_for(lambda m: m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 1)
        yield sitl, client
    finally:
        sitl.stop()
        client.close()


def command(sender, client: MavTestClient, cmd: int, *params: float, timeout_s: float = 1.5) -> int | None:
    """Send COMMAND_LONG through ``sender``; the ACK's result seen by ``client``, or None."""
    p = list(params) + [0.0] * (7 - len(params))
    sender.send(M.MAVLink_command_long_message(1, 1, cmd, 0, *p))
    try:
        ack = client.wait_for(lambda m: m.get_type() == "COMMAND_ACK" and m.command == cmd, timeout_s)
    except TimeoutError:
        return None
    return int(ack.result)


def stream(client: MavTestClient, wall_s: float, forward_m_s: float = 1.0) -> None:
    end = time.monotonic() + wall_s
    while time.monotonic() < end:
        client.body_velocity(forward_m_s)
        client.pump(0.02)
        time.sleep(0.01)


def settle(client: MavTestClient, wall_s: float) -> None:
    end = time.monotonic() + wall_s
    while time.monotonic() < end:
        client.pump(0.05)


def test_the_sitl_signs_everything_it_sends(signed_sitl) -> None:
    _, client = signed_sitl
    msgs = [client.wait_for(lambda m, k=kind: m.get_type() == k) for kind in ("HEARTBEAT", "ATTITUDE", "SYSTEM_TIME")]
    assert all(m.get_signed() for m in msgs)  # checked against KEY by the client's parser


def test_a_signed_client_arms_takes_off_and_flies_offboard(signed_sitl) -> None:
    _, client = signed_sitl
    assert client.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
    assert client.command(M.MAV_CMD_NAV_TAKEOFF, *nan7()) == M.MAV_RESULT_ACCEPTED
    client.wait_for(lambda m: m.get_type() == "LOCAL_POSITION_NED" and m.z < -2.0, timeout_s=10)
    stream(client, 0.3)
    assert client.command(M.MAV_CMD_DO_SET_MODE, 1, 6, 0) == M.MAV_RESULT_ACCEPTED
    x0 = client.latest["LOCAL_POSITION_NED"].x
    stream(client, 1.0)  # 4 s of flight at 1 m/s
    assert client.mode_custom() == OFFBOARD and client.latest["LOCAL_POSITION_NED"].x - x0 > 1.0


@pytest.mark.parametrize("intruder_key", [None, secrets.token_bytes(32)], ids=["unsigned", "wrong-key"])
def test_an_intruders_arm_mode_and_setpoints_have_no_effect(signed_sitl, intruder_key: bytes | None) -> None:
    _, client = signed_sitl
    intruder = Intruder(client.peer, intruder_key)  # type: ignore[arg-type]
    try:
        intruder.send(M.MAVLink_heartbeat_message(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3))
        assert command(intruder, client, M.MAV_CMD_COMPONENT_ARM_DISARM, 1) is None
        assert command(intruder, client, M.MAV_CMD_DO_SET_MODE, 1, 6, 0) is None
        intruder.send(M.MAVLink_set_mode_message(1, 1, OFFBOARD))
        for _ in range(20):
            intruder.send(M.MAVLink_set_position_target_local_ned_message(
                0, 1, 1, 8, 0x5C7, 0, 0, 0, 3.0, 0, -2.0, 0, 0, 0, 0, 0))
            intruder.send(M.MAVLink_manual_control_message(1, 1000, 0, 1000, 0, 1))
        settle(client, 1.0)
        assert not client.armed() and client.mode_custom() != OFFBOARD
        pos = client.latest["LOCAL_POSITION_NED"]
        assert abs(pos.vz) < 0.05 and abs(pos.vx) < 0.05  # still on the ground, not moved
        # the vehicle kept talking to the signed client, and still obeys it
        assert client.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
    finally:
        intruder.close()


def test_a_replayed_signed_command_has_no_effect(signed_sitl) -> None:
    _, client = signed_sitl
    arm = M.MAVLink_command_long_message(1, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
    recorded = bytes(arm.pack(client.mav))
    client.send_raw(recorded)
    client.wait_for(lambda m: m.get_type() == "COMMAND_ACK" and m.command == M.MAV_CMD_COMPONENT_ARM_DISARM)
    assert client.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 0) == M.MAV_RESULT_ACCEPTED
    settle(client, 0.5)
    assert not client.armed()
    intruder = Intruder(client.peer)  # type: ignore[arg-type]
    try:
        intruder.send_raw(recorded)  # the same bytes, from elsewhere
        client.send_raw(recorded)  # and from the client's own address
        settle(client, 1.0)
        assert not client.armed()
    finally:
        intruder.close()


def test_setup_signing_over_the_wired_link_then_unsigned_is_refused(client: MavTestClient) -> None:
    sitl = start_sitl(client.port, clock="realtime", camera=False, extra_args=["--speed", "4", "--tcp", "0"])
    try:
        client.wait_for(lambda m: m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 1)
        assert client.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED  # no key yet
        assert client.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 0) == M.MAV_RESULT_ACCEPTED
        # unsigned SETUP_SIGNING over UDP is refused: UDP is not the wired first link
        client.send(M.MAVLink_setup_signing_message(1, 1, list(KEY), 1))
        assert client.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
        assert client.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 0) == M.MAV_RESULT_ACCEPTED
        wire = socket.create_connection(("127.0.0.1", int(sitl.ports["tcp"])), timeout=2.0)
        try:
            wire.sendall(M.MAVLink_setup_signing_message(1, 1, list(KEY), 1).pack(M.MAVLink(None, 255, 190)))
            settle(client, 0.5)
            assert command(client, client, M.MAV_CMD_COMPONENT_ARM_DISARM, 1) is None  # unsigned now ignored
            signed = signed_client(KEY)
            signed.sock.close()
            signed.sock, signed.peer = client.sock, client.peer
            assert signed.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
        finally:
            wire.close()
    finally:
        sitl.stop()
