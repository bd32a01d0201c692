"""The SITL as another process, over real loopback UDP: flight, lockstep, bad input."""

from __future__ import annotations

import math
import os
import struct
import time
from collections.abc import Iterator

import pytest
from pymavlink.dialects.v20 import common as M

from companion.simulator import SimulatorClient, SitlProcess, start_sitl
from tests.mav_client import MavTestClient, nan7

pytestmark = [pytest.mark.realtime, pytest.mark.e2e]

OFFBOARD = 6 << 16
LOITER = (4 << 16) | (3 << 24)
LAND = (4 << 16) | (6 << 24)


@pytest.fixture
def sitl_fast(client: MavTestClient) -> Iterator[SitlProcess]:
    """Real-time clock at 4x: MAVLink behaves as with a real vehicle, tests stay short."""
    sitl = start_sitl(client.port, clock="realtime", camera=False, extra_args=["--speed", "4"])
    yield sitl
    sitl.stop()


def stream_until(client: MavTestClient, seconds_wall: float, forward: float = 0.0, down: float = 0.0) -> None:
    end = time.monotonic() + seconds_wall
    while time.monotonic() < end:
        client.body_velocity(forward, 0.0, down)
        client.pump(0.02)


def test_pymavlink_client_arms_takes_off_flies_offboard_and_lands(client: MavTestClient, sitl_fast: SitlProcess) -> None:
    hb = client.wait_for(lambda m: m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 1)
    assert hb.autopilot == M.MAV_AUTOPILOT_PX4 and hb.type == M.MAV_TYPE_QUADROTOR
    assert client.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION) == M.MAV_RESULT_ACCEPTED
    client.wait_for(lambda m: m.get_type() == "AUTOPILOT_VERSION")
    assert client.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
    assert client.command(M.MAV_CMD_NAV_TAKEOFF, *nan7()) == M.MAV_RESULT_ACCEPTED
    client.wait_for(lambda m: m.get_type() == "LOCAL_POSITION_NED" and m.z < -2.3, timeout_s=10)
    assert client.command(M.MAV_CMD_DO_SET_MODE, 1, 6, 0) == M.MAV_RESULT_DENIED  # no stream yet
    stream_until(client, 0.3, forward=1.0)
    assert client.command(M.MAV_CMD_DO_SET_MODE, 1, 6, 0) == M.MAV_RESULT_ACCEPTED
    x0 = client.latest["LOCAL_POSITION_NED"].x
    stream_until(client, 1.0, forward=1.0)  # ~4 s of simulation
    pos = client.latest["LOCAL_POSITION_NED"]
    assert client.mode_custom() == OFFBOARD
    assert pos.x - x0 > 2.0 and pos.vx == pytest.approx(1.0, abs=0.2)
    assert client.command(M.MAV_CMD_NAV_LAND) == M.MAV_RESULT_ACCEPTED
    client.wait_for(lambda m: m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 1
                    and not m.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED, timeout_s=15)
    ess = client.wait_for(lambda m: m.get_type() == "EXTENDED_SYS_STATE")
    assert ess.landed_state == M.MAV_LANDED_STATE_ON_GROUND


def test_params_and_unknown_commands(client: MavTestClient, sitl_fast: SitlProcess) -> None:
    client.wait_for(lambda m: m.get_type() == "HEARTBEAT")
    client.send(M.MAVLink_param_request_read_message(1, 1, b"MIS_TAKEOFF_ALT", -1))
    pv = client.wait_for(lambda m: m.get_type() == "PARAM_VALUE")
    assert pv.param_id == "MIS_TAKEOFF_ALT" and pv.param_value == pytest.approx(2.5)
    client.send(M.MAVLink_param_set_message(1, 1, b"MIS_TAKEOFF_ALT", 4.0, M.MAV_PARAM_TYPE_REAL32))
    pv = client.wait_for(lambda m: m.get_type() == "PARAM_VALUE" and m.param_id == "MIS_TAKEOFF_ALT")
    assert pv.param_value == pytest.approx(4.0)
    assert client.command(31999) == M.MAV_RESULT_UNSUPPORTED
    assert client.command(31999) == M.MAV_RESULT_UNSUPPORTED  # repeated: still one ACK each
    assert client.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_ATTITUDE, -1) == M.MAV_RESULT_ACCEPTED
    client.pump(0.5)
    client.latest.pop("ATTITUDE", None)
    client.pump(0.5)
    assert "ATTITUDE" not in client.latest


def test_garbage_nan_and_a_vanishing_client_fail_safe(client: MavTestClient, sitl_fast: SitlProcess) -> None:
    client.wait_for(lambda m: m.get_type() == "HEARTBEAT")
    ctl = SimulatorClient("127.0.0.1", sitl_fast.control_port)
    ctl.reset(seed=5)
    rng = __import__("random").Random(1)
    for _ in range(200):  # random bytes and garbled MAVLink frames
        client.send_raw(bytes(rng.getrandbits(8) for _ in range(rng.randint(1, 300))))
    good = M.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3).pack(client.mav)
    client.send_raw(good[:5] + b"\xff" * 4 + good[9:])
    client.send_raw(b"\xfd" + struct.pack("<B", 250) + b"\x00" * 20)
    client.body_velocity(math.nan, 0.0)  # NaN setpoint: refused
    client.body_velocity(1e9, -1e9)  # out of range: clamped
    stream_until(client, 0.3)
    assert client.command(M.MAV_CMD_DO_SET_MODE, 1, 6, 0) == M.MAV_RESULT_ACCEPTED
    stream_until(client, 0.5)
    # the client vanishes mid-flight: hold after COM_OF_LOSS_T, land after COM_OBL_LAND_T
    client.wait_for(lambda m: m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 1 and m.custom_mode == LOITER, 5)
    client.wait_for(lambda m: m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 1 and m.custom_mode == LAND, 10)
    assert any("Setpoint refused" in t for t in client.statustexts)
    truth = ctl.truth()
    assert all(math.isfinite(x) for x in truth["vehicle_ned"])
    ctl.close()
    assert sitl_fast.proc.poll() is None  # still running


def lockstep_trace(seed: int, frames: int) -> list[tuple]:
    """Fly a fixed pattern in lockstep; return every LOCAL_POSITION_NED and ATTITUDE seen."""
    c = MavTestClient()
    sitl = start_sitl(c.port, clock="lockstep", camera=False)
    try:
        c.wait_for(lambda m: m.get_type() == "SYSTEM_TIME")
        ctl = SimulatorClient("127.0.0.1", sitl.control_port)
        reset = ctl.reset(seed=seed)
        trace: list[tuple] = []
        answered = 0
        while answered < frames:
            for m in c.pump(2.0):
                if m.get_type() in ("LOCAL_POSITION_NED", "ATTITUDE") and m.time_boot_ms > reset["time_boot_ms"]:
                    trace.append(tuple(m.to_dict().values()))
                if m.get_type() == "SYSTEM_TIME" and m.time_boot_ms > reset["time_boot_ms"]:
                    k = answered
                    if answered == 2:  # before the answer: sent after it, it could miss this frame
                        c.send(M.MAVLink_command_long_message(1, 1, M.MAV_CMD_DO_SET_MODE, 0, 1, 6, 0, 0, 0, 0, 0))
                    c.body_velocity(math.sin(0.1 * k), math.cos(0.07 * k), 0.3 * math.sin(0.05 * k), 0.2, echo_ms=m.time_boot_ms)
                    answered += 1
        ctl.close()
        return trace
    finally:
        sitl.stop()
        c.close()


def test_lockstep_is_bit_for_bit_deterministic_for_a_seed() -> None:
    a = lockstep_trace(seed=9, frames=60)
    b = lockstep_trace(seed=9, frames=60)
    assert len(a) > 100
    assert a == b
    c = lockstep_trace(seed=10, frames=20)
    assert c[:20] != a[:20]


@pytest.mark.skipif(os.environ.get("CI_NO_SIGNALS") == "1", reason="signals unavailable")
def test_sitl_exits_cleanly_on_sigterm(client: MavTestClient) -> None:
    sitl = start_sitl(client.port, clock="realtime", camera=False)
    client.wait_for(lambda m: m.get_type() == "HEARTBEAT")
    sitl.proc.terminate()
    assert sitl.proc.wait(5) == 0
    sitl.stop()
