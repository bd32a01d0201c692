"""Precision landing over real loopback sockets: a pymavlink client takes off in the SITL, sends
LANDING_TARGET computed from the SITL's true pad position (on its moving ground vehicle), asks
for precision landing as each autopilot wants it, and the vehicle lands on the pad."""

from __future__ import annotations

import math
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as M

from companion.simulator import SimulatorClient, SitlProcess, start_sitl
from sitl.landing_target import FRAME_BODY_FRD, FRAME_LOCAL_NED, ned_to_body
from sitl.personality import REBOOT_S
from tests.mav_client import MavTestClient, nan7

pytestmark = [pytest.mark.realtime, pytest.mark.e2e]
PRECLAND = (4 << 16) | (9 << 24)
SPEED = 4.0  # simulation seconds per wall second
TOUCHDOWN_WITHIN_M = {"px4": 0.3, "ardupilot": 0.3}  # the stated distance from the pad's centre
PAD_SPEED_M_S = {"px4": 0.1, "ardupilot": 0.3}  # PX4's precland has no feed-forward: it lags v / Kp


@pytest.fixture(params=["px4", "ardupilot"])
def flight(request: pytest.FixtureRequest, client: MavTestClient, tmp_path: Path) -> Iterator[tuple[str, SitlProcess]]:
    config = tmp_path / "sitl.toml"
    config.write_text("[sitl.personality]\nprearm_settle_s = 1.0\n")
    sitl = start_sitl(client.port, clock="realtime", camera=False, config=config,
                      extra_args=["--speed", str(SPEED), "--autopilot", request.param])
    yield request.param, sitl
    sitl.stop()


def send_target(client: MavTestClient, truth: dict, kind: str) -> None:
    """The pad as each autopilot takes it: PX4 LOCAL_NED in its own local frame, ArduPilot
    BODY_FRD from the vehicle (the companion's contract, companion/link/landing_target.py)."""
    rel = [p - v for p, v in zip(truth["pad_ned"], truth["vehicle_ned"])]
    body = ned_to_body((rel[0], rel[1], rel[2]), tuple(truth["attitude_rad"]))  # type: ignore[arg-type]
    distance = math.sqrt(sum(c * c for c in rel))
    angle_x, angle_y = math.atan2(body[1], body[2]), math.atan2(-body[0], body[2])
    if kind == "px4":
        local = client.latest["LOCAL_POSITION_NED"]
        frame, xyz = FRAME_LOCAL_NED, (local.x + rel[0], local.y + rel[1], local.z + rel[2])
    else:
        frame, xyz = FRAME_BODY_FRD, body
    client.send(M.MAVLink_landing_target_message(
        int(truth["time_boot_ms"]) * 1000, 0, frame, angle_x, angle_y, distance, 0.1, 0.1, *xyz,
        [1.0, 0.0, 0.0, 0.0], M.LANDING_TARGET_TYPE_VISION_FIDUCIAL, 1))


def take_off(client: MavTestClient, kind: str) -> None:
    client.wait_for(lambda m: m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 1)
    for msg_id in (M.MAVLINK_MSG_ID_LOCAL_POSITION_NED, M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE):
        client.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, msg_id, 50_000)
    if kind == "px4":
        client.send(M.MAVLink_param_set_message(1, 1, b"MIS_TAKEOFF_ALT", 4.0, M.MAV_PARAM_TYPE_REAL32))
        assert client.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
        assert client.command(M.MAV_CMD_NAV_TAKEOFF, *nan7()) == M.MAV_RESULT_ACCEPTED
    else:
        deadline = time.monotonic() + 10
        while client.command(M.MAV_CMD_DO_SET_MODE, 1, 4) != M.MAV_RESULT_ACCEPTED and time.monotonic() < deadline:
            client.pump(0.2)
        while client.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1) != M.MAV_RESULT_ACCEPTED and time.monotonic() < deadline:
            client.pump(0.2)
        assert client.command(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, 0, 0, 4.0) == M.MAV_RESULT_ACCEPTED


def ask_for_precision_landing(client: MavTestClient, kind: str) -> None:
    if kind == "px4":
        assert client.command(M.MAV_CMD_DO_SET_MODE, 1 | 128, 4, 9) == M.MAV_RESULT_ACCEPTED
        client.wait_for(lambda m: m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 1
                        and m.custom_mode == PRECLAND, timeout_s=5)
        return
    # the moving-target option, and no descent until within 0.3 m (the default 2.5 m lets it
    # touch down 0.46 m behind a 0.3 m/s pad: measured)
    params = (("PLND_ENABLED", 1.0), ("PLND_TYPE", 1.0), ("PLND_OPTIONS", 1.0), ("PLND_XY_DIST_MAX", 0.3))
    for name, value in params:
        ptype = M.MAV_PARAM_TYPE_REAL32 if name == "PLND_XY_DIST_MAX" else M.MAV_PARAM_TYPE_INT8
        client.send(M.MAVLink_param_set_message(1, 1, name.encode(), value, ptype))
        client.wait_for(lambda m, n=name: m.get_type() == "PARAM_VALUE" and m.param_id == n)
    assert client.command(M.MAV_CMD_DO_SET_MODE, 1 | 128, 9) == M.MAV_RESULT_ACCEPTED


def plnd_on_at_boot(client: MavTestClient) -> None:
    """ArduCopter makes its precision landing backend at boot: PLND_TYPE, then a reboot, which
    is silent for REBOOT_S (take_off waits for the HEARTBEAT after it and asks for the streams)."""
    client.wait_for(lambda m: m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 1)
    client.send(M.MAVLink_param_set_message(1, 1, b"PLND_TYPE", 1.0, M.MAV_PARAM_TYPE_INT8))
    client.wait_for(lambda m: m.get_type() == "PARAM_VALUE" and m.param_id == "PLND_TYPE")
    assert client.command(M.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, 1) == M.MAV_RESULT_ACCEPTED
    silent_until = time.monotonic() + 0.8 * REBOOT_S / SPEED
    while time.monotonic() < silent_until:
        assert not any(m.get_srcComponent() == 1 for m in client.pump(0.1)), "the autopilot spoke while rebooting"
    client.inbox.clear()


def test_precision_landing_on_a_moving_pad(client: MavTestClient, flight: tuple[str, SitlProcess]) -> None:
    kind, sitl = flight
    sim = SimulatorClient("127.0.0.1", sitl.control_port)
    try:
        if kind == "ardupilot":
            plnd_on_at_boot(client)
        take_off(client, kind)
        client.wait_for(lambda m: m.get_type() == "LOCAL_POSITION_NED" and m.z < -3.5, timeout_s=20)
        sim.request("set_ground_vehicle", velocity_ne_m_s=[PAD_SPEED_M_S[kind], 0.0])
        if kind == "ardupilot":  # PLND on before the targets (AC_PrecLand reads nothing while off)
            ask_for_precision_landing(client, kind)
        end, asked = time.monotonic() + 60.0, kind == "ardupilot"
        started = time.monotonic()
        while time.monotonic() < end:
            truth = sim.truth()
            if truth["touchdown"] is not None:
                break
            send_target(client, truth, kind)
            client.pump(0.025)
            if not asked and time.monotonic() - started > 0.5:
                ask_for_precision_landing(client, kind)
                asked = True
        td = sim.truth()["touchdown"]
        assert td is not None, (kind, client.statustexts[-10:])
        print(f"{kind}: touchdown {td['distance_to_pad_m']:.3f} m from the pad centre, pad at "
              f"{PAD_SPEED_M_S[kind]} m/s; {client.statustexts[-6:]}")
        assert td["on_pad"] and td["distance_to_pad_m"] < TOUCHDOWN_WITHIN_M[kind], (td, client.statustexts[-10:])
    finally:
        sim.close()


def test_nan_landing_target_is_refused_with_a_warning(client: MavTestClient, flight: tuple[str, SitlProcess]) -> None:
    kind, _ = flight
    client.wait_for(lambda m: m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 1)
    client.send(M.MAVLink_landing_target_message(0, 0, FRAME_LOCAL_NED, math.nan, 0.0, 3.0, 0.1, 0.1, 0.0, 0.0, 0.0,
                                                 [1.0, 0.0, 0.0, 0.0], 2, 0))
    text = client.wait_for(lambda m: m.get_type() == "STATUSTEXT" and "non-finite" in m.text, timeout_s=5)
    assert "angle_x" in text.text
