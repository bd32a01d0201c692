"""The pymavlink link against the fake vehicle over real loopback UDP."""

from __future__ import annotations

import dataclasses
import math
import socket
import struct
import time
from collections.abc import Callable, Iterator

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega
from pymavlink.dialects.v20 import common as mavlink

import companion.link.px4_modes as px4_modes
from companion.config import LinkConfig
from companion.errors import CommandRejected, ConfigError, LinkLost, LinkTimeout
from companion.link import ManualControlMessage, VehicleSnapshot, open_link
from companion.link.connection import parse_connection
from companion.link.mavlink_link import MavlinkLink
from companion.msg.setpoint import VelocitySetpoint
from companion.testing import FakeVehicle
from companion.testing.link_contract import run_link_contract
from tests.conftest import wait_until as _until

pytestmark = pytest.mark.realtime  # flies in real time: a higher priority where allowed


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture
def make_link(fake: FakeVehicle) -> Iterator[Callable[..., MavlinkLink]]:
    links: list[MavlinkLink] = []

    def make(connect: bool = True, tlog_path=None, **overrides) -> MavlinkLink:
        cfg = LinkConfig(connection=fake.connection_string, command_timeout_s=0.3, **overrides)
        link = MavlinkLink(cfg, tlog_path=tlog_path)
        links.append(link)
        if connect:
            link.connect(timeout_s=2.0)
        return link

    yield make
    for link in links:
        link.close()


# ------------------------------------------------------------------ pure pieces
@pytest.mark.parametrize(
    ("text", "kind", "device", "baud"),
    [
        ("udpin:0.0.0.0:14540", "udpin", "udpin:0.0.0.0:14540", 57600),
        ("udpout:127.0.0.1:14580", "udpout", "udpout:127.0.0.1:14580", 57600),
        ("udp:127.0.0.1:14550", "udpin", "udpin:127.0.0.1:14550", 57600),
        ("tcp:127.0.0.1:5760", "tcp", "tcp:127.0.0.1:5760", 57600),
        ("tcpin:0.0.0.0:5760", "tcpin", "tcpin:0.0.0.0:5760", 57600),
        ("/dev/ttyACM0,921600", "serial", "/dev/ttyACM0", 921600),
        ("/dev/ttyUSB0:115200", "serial", "/dev/ttyUSB0", 115200),
        ("serial:/dev/ttyUSB0:57600", "serial", "/dev/ttyUSB0", 57600),
        ("/dev/ttyUSB0", "serial", "/dev/ttyUSB0", 57600),
        ("COM3", "serial", "COM3", 57600),
        ("udpin://0.0.0.0:14540", "udpin", "udpin:0.0.0.0:14540", 57600),  # MAVSDK's spelling
        ("serial:///dev/ttyUSB0:921600", "serial", "/dev/ttyUSB0", 921600),
    ],
)
def test_connection_strings_parse_as_mavlink_tools_write_them(text, kind, device, baud) -> None:
    spec = parse_connection(text)
    assert (spec.kind, spec.device, spec.baud) == (kind, device, baud)


def test_serial_baud_from_config_applies_only_without_suffix() -> None:
    assert parse_connection("/dev/ttyUSB0", baud=921600).baud == 921600
    assert parse_connection("/dev/ttyUSB0,57600", baud=921600).baud == 57600


@pytest.mark.parametrize("text", ["", "udpin:14540", "tcp:host:port", "udpout:1.2.3.4:70000"])
def test_bad_connection_strings_say_what_is_expected(text: str) -> None:
    with pytest.raises(ConfigError, match="connection|empty"):
        parse_connection(text)


@pytest.mark.parametrize("text", ["bogus://x", "udpn:127.0.0.1:14540", "localhost"])
def test_unknown_schemes_are_refused_naming_the_accepted_forms(text: str) -> None:
    """Not handed to pymavlink as a serial device (an int() error and advice about dialout)."""
    with pytest.raises(ConfigError) as err:
        parse_connection(text)
    message = str(err.value)
    assert text in message and "udpin:HOST:PORT" in message and "/dev/ttyACM0" in message
    assert "int()" not in message and "dialout" not in message


def test_px4_modes_round_trip_and_aliases() -> None:
    for name, (main, sub) in px4_modes.PX4_MODES.items():
        assert px4_modes.decode(main << 16 | sub << 24) == name
    assert px4_modes.encode("hold") == (4, 3)
    assert px4_modes.custom_mode("OFFBOARD") == 6 << 16
    assert px4_modes.decode(0x7F << 16).startswith("UNKNOWN")


def test_velocity_setpoint_refuses_non_finite() -> None:
    for bad in (math.nan, math.inf, -math.inf):
        with pytest.raises(ValueError, match="finite"):
            VelocitySetpoint(0.0, bad, 0.0, 0.0)
    with pytest.raises(TypeError):
        VelocitySetpoint("1", 0.0, 0.0, 0.0)  # type: ignore[arg-type]


def test_open_link_rejects_unknown_kind() -> None:
    with pytest.raises(ConfigError, match="pymavlink"):
        open_link(LinkConfig(), kind="grpc")  # type: ignore[arg-type]


# ------------------------------------------------------------------ handshake, rates
def test_handshake_heartbeats_both_ways(fake, make_link) -> None:
    link = make_link()
    snapshot = link.state()
    assert snapshot is not None and snapshot.autopilot == "PX4" and snapshot.system_id == 1
    assert link.link_alive()
    ours = fake.wait_for("HEARTBEAT")
    assert ours.type == mavlink.MAV_TYPE_ONBOARD_CONTROLLER
    assert ours.autopilot == mavlink.MAV_AUTOPILOT_INVALID
    assert (ours.get_srcSystem(), ours.get_srcComponent()) == (1, 191)


def test_link_listening_with_udpin_finds_a_vehicle_that_sends_first() -> None:
    port = free_udp_port()
    with FakeVehicle(remote=("127.0.0.1", port), heartbeat_period_s=0.1) as fake:
        with MavlinkLink(LinkConfig(connection=f"udpin:127.0.0.1:{port}")) as link:
            link.connect(timeout_s=2.0)
            link.set_mode("OFFBOARD")  # replies reach the vehicle at the address it came from
            assert fake.mode == "OFFBOARD"


def test_connect_without_vehicle_heartbeat_times_out(fake, make_link) -> None:
    fake.heartbeat_enabled = False
    link = make_link(connect=False)
    started = time.monotonic()
    with pytest.raises(LinkTimeout, match="HEARTBEAT"):
        link.connect(timeout_s=0.3)
    assert time.monotonic() - started < 1.0


def test_requests_the_telemetry_rates_it_needs(fake, make_link) -> None:
    make_link(telemetry_rate_hz=40.0, status_rate_hz=2.0)
    assert fake.requested_intervals_us() == {
        mavlink.MAVLINK_MSG_ID_ATTITUDE: pytest.approx(25_000),
        mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: pytest.approx(25_000),
        mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: pytest.approx(500_000),
        mavlink.MAVLINK_MSG_ID_HOME_POSITION: pytest.approx(2_000_000),  # heights are taken from home
    }


def test_unread_streams_are_stopped_only_when_asked(fake, make_link) -> None:
    make_link(stop_unread_streams=True)
    intervals = fake.requested_intervals_us()
    assert intervals[mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT] == -1  # -1: stop the stream
    assert intervals[mavlink.MAVLINK_MSG_ID_SYS_STATUS] == -1
    assert intervals[mavlink.MAVLINK_MSG_ID_ATTITUDE] > 0  # what the companion reads stays


def test_rate_requests_report_refusals_instead_of_raising(fake, make_link) -> None:
    link = make_link()
    fake.set_ack_commands(False)
    assert link.request_rates({"ATTITUDE": 10.0}) == {"ATTITUDE": "TIMEOUT"}
    with pytest.raises(ValueError, match="unknown message"):
        link.request_rates({"NOT_A_MESSAGE": 1.0})


# ------------------------------------------------------------------ commands
def test_mode_change_sends_px4_custom_mode_and_snapshot_follows(fake, make_link) -> None:
    link = make_link()
    link.set_mode("OFFBOARD")
    cmd = fake.commands(mavlink.MAV_CMD_DO_SET_MODE)[-1]
    assert int(cmd.param1) & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    assert (cmd.param2, cmd.param3) == (6, 0)
    assert _until(lambda: link.state().mode == "OFFBOARD")
    link.set_mode("HOLD")
    assert _until(lambda: link.state().mode == "AUTO.LOITER")


def test_unknown_mode_is_refused_without_sending(fake, make_link) -> None:
    link = make_link()
    with pytest.raises(CommandRejected, match="UNSUPPORTED"):
        link.set_mode("WARP")
    assert fake.commands(mavlink.MAV_CMD_DO_SET_MODE) == []


@pytest.mark.parametrize("result", ["DENIED", "TEMPORARILY_REJECTED", "FAILED"])
def test_arming_refusal_raises_command_rejected_with_result_name(fake, make_link, result) -> None:
    link = make_link()
    fake.set_arm_result(result)
    with pytest.raises(CommandRejected) as info:
        link.arm()
    assert info.value.result == result and info.value.command == "arm"
    assert "retry" in str(info.value)  # the message says what to do
    assert not link.state().armed
    assert len(fake.commands(mavlink.MAV_CMD_COMPONENT_ARM_DISARM)) == 1  # no retry on refusal


def test_ignored_command_is_retried_then_times_out(fake, make_link) -> None:
    link = make_link(command_retries=2)
    fake.set_ack_commands(False)
    with pytest.raises(LinkTimeout, match="3 attempt"):
        link.arm()
    sent = fake.commands(mavlink.MAV_CMD_COMPONENT_ARM_DISARM)
    assert [m.confirmation for m in sent] == [0, 1, 2]


def test_a_lost_param_echo_is_asked_for_again_as_often_as_a_command(fake, make_link) -> None:
    """A loaded autopilot loses or delays PARAM_VALUE as it does COMMAND_ACK: PARAM_SET is sent
    again every command_timeout_s, and gives up only after as many tries as a command gets."""
    link = make_link(command_retries=5)  # six tries: the fourth is echoed, with room for a slow machine
    fake.drop_param_echoes(3)
    assert link.set_param("SIH_MASS", 1.1) == pytest.approx(1.1)
    assert [m.param_id for m in fake.messages("PARAM_SET")].count("SIH_MASS") >= 4
    fake.drop_param_echoes(0)
    hasty = make_link(command_retries=1)
    fake.drop_param_echoes(3)
    assert hasty.set_param("SIH_KDV", 0.3) is None  # two tries, both lost
    assert [m.param_id for m in fake.messages("PARAM_SET")].count("SIH_KDV") <= 2


def test_an_episode_start_waits_for_its_parameter_echoes_longer_than_a_command(fake, make_link) -> None:
    """PX4 SIH at 4x beside a full test run left SIH_MASS unechoed for all of a command's tries,
    and the episode was lost: an episode's parameters are asked for again until PARAM_BUDGET_S."""
    from companion.link.sim_params import PX4, AutopilotSim, SimEpisode

    link = make_link(command_retries=1)  # a command gets two tries of 0.3 s
    fake.autopilot.state.params.update(SIH_MASS=1.0, SIH_KDV=0.5)
    sim = AutopilotSim(lambda seed: SimEpisode(), height_m=9.5, mass_scale=1.1)
    fake.drop_param_echoes(4)  # more than a command's tries
    notes = sim.prepare_episode(link, PX4, seed=0)
    assert fake.autopilot.state.params["SIH_MASS"] == pytest.approx(1.1)
    assert "SIH_MASS=1.1" in notes[0]
    assert [m.param_id for m in fake.messages("PARAM_SET")].count("SIH_MASS") >= 5


def test_arm_takeoff_land_reach_the_vehicle(fake, make_link) -> None:
    link = make_link()
    link.arm()
    assert _until(lambda: link.state().armed)
    link.takeoff(3.0)
    assert fake.messages("PARAM_SET")[-1].param_value == pytest.approx(3.0)
    assert _until(lambda: link.state().position_ned_m[2] < -2.9, 4.0)
    assert link.state().in_air
    link.land()
    assert _until(lambda: link.state().mode == "AUTO.LAND")
    with pytest.raises(ValueError, match="takeoff altitude"):
        link.takeoff(math.nan)


# ------------------------------------------------------------------ setpoints
def test_velocity_setpoint_content_frame_and_type_mask(fake, make_link) -> None:
    link = make_link()
    link.send_velocity_body(VelocitySetpoint(1.5, -0.5, 0.25, 0.3), echo_time_boot_ms=12345)
    msg = fake.wait_for("SET_POSITION_TARGET_LOCAL_NED")
    assert msg.coordinate_frame == mavlink.MAV_FRAME_BODY_NED == 8
    assert msg.type_mask == 0x5C7
    assert (msg.vx, msg.vy, msg.vz) == pytest.approx((1.5, -0.5, 0.25))
    assert msg.yaw_rate == pytest.approx(0.3)
    assert (msg.x, msg.y, msg.z, msg.yaw) == (0.0, 0.0, 0.0, 0.0)
    assert msg.time_boot_ms == 12345
    assert (msg.target_system, msg.target_component) == (1, 1)


def test_position_setpoint_uses_local_ned_with_position_and_yaw(fake, make_link) -> None:
    link = make_link()
    link.send_position_ned(3.0, -4.0, -8.0, 1.0)
    msg = fake.wait_for("SET_POSITION_TARGET_LOCAL_NED")
    assert msg.coordinate_frame == mavlink.MAV_FRAME_LOCAL_NED
    assert msg.type_mask == 0x9F8
    assert (msg.x, msg.y, msg.z, msg.yaw) == pytest.approx((3.0, -4.0, -8.0, 1.0))


def test_out_of_range_setpoints_are_refused_and_never_sent(fake, make_link) -> None:
    link = make_link(setpoint_max_speed_m_s=3.0)
    with pytest.raises(ValueError, match="3.0 m/s"):
        link.send_velocity_body(VelocitySetpoint(0.0, 0.0, 3.5, 0.0))
    with pytest.raises(ValueError, match="yaw rate"):
        link.send_velocity_body(VelocitySetpoint(0.0, 0.0, 0.0, -9.0))
    with pytest.raises(ValueError, match="uint32"):
        link.send_velocity_body(VelocitySetpoint.zero(), echo_time_boot_ms=2**32)
    with pytest.raises(ValueError, match="finite"):
        link.send_position_ned(0.0, math.inf, -2.0, 0.0)
    time.sleep(0.1)
    assert fake.messages("SET_POSITION_TARGET_LOCAL_NED") == []
    assert link.stats().setpoints_sent == 0


def test_lockstep_frames_are_waited_for_and_echoed() -> None:
    with FakeVehicle(stream_rate_hz=0.0, frame_period_ms=95) as fake:
        with MavlinkLink(LinkConfig(connection=fake.connection_string)) as link:
            link.connect(timeout_s=2.0)
            assert link.wait_frame(-1, 0.2) is None  # no frame marker yet
            t1 = fake.send_frame()
            frame = link.wait_frame(-1, 1.0)
            assert frame is not None and frame.frame_time_boot_ms == t1 == 95
            assert frame.position_valid and frame.time_boot_ms == t1  # telemetry came first
            assert link.wait_frame(t1, 0.1) is None
            link.send_velocity_body(VelocitySetpoint.zero())  # no echo: answers newest frame
            link.send_velocity_body(VelocitySetpoint.zero(), echo_time_boot_ms=t1)
            t2 = fake.send_frame()
            assert link.wait_frame(t1, 1.0).frame_time_boot_ms == t2 == 190
            _until(lambda: len(fake.messages("SET_POSITION_TARGET_LOCAL_NED")) == 2)
            stamps = [m.time_boot_ms for m in fake.messages("SET_POSITION_TARGET_LOCAL_NED")]
            assert stamps == [t1, t1]


def test_non_finite_telemetry_is_ignored_and_counted(fake, make_link) -> None:
    link = make_link()
    assert _until(lambda: link.state().position_valid)
    fake.stream_rate_hz = 0.0
    time.sleep(0.1)
    nan = float("nan")
    fake.send_message(fake.encoder.local_position_ned_encode(1, nan, 0.0, 0.0, 0.0, 0.0, 0.0))
    assert _until(lambda: link.stats().telemetry_rejected == 1)
    assert all(math.isfinite(v) for v in link.state().position_ned_m)


# ------------------------------------------------------------------ loss and return
def test_link_loss_raises_then_resumes_by_itself(fake, make_link) -> None:
    link = make_link(link_lost_s=0.3)
    fake.go_silent()
    assert _until(lambda: not link.link_alive(), 2.0)
    with pytest.raises(LinkLost, match="resumes by itself"):
        link.send_velocity_body(VelocitySetpoint.zero())
    with pytest.raises(LinkLost):
        link.arm()
    with pytest.raises(LinkLost):
        link.wait_frame(10**9, 0.5)
    fake.resume()
    assert _until(link.link_alive, 2.0)
    link.send_velocity_body(VelocitySetpoint.zero())
    fake.wait_for("SET_POSITION_TARGET_LOCAL_NED")
    stats = link.stats()
    assert (stats.link_losses, stats.reconnections) == (1, 1)


def test_calls_before_connect_and_after_close_raise_link_lost(fake, make_link) -> None:
    link = make_link(connect=False)
    assert link.state() is None and not link.link_alive()
    with pytest.raises(LinkLost, match="connect"):
        link.arm()
    link.connect(2.0)
    link.close()
    link.close()  # idempotent
    with pytest.raises(LinkLost):
        link.send_velocity_body(VelocitySetpoint.zero())


# ------------------------------------------------------------------ MANUAL_CONTROL
def test_manual_control_reaches_the_callback_normalised(fake, make_link) -> None:
    link = make_link()
    got: list[ManualControlMessage] = []
    link.on_manual_control(got.append)
    fake.send_manual_control(x=500, y=-1000, z=1000, r=250, buttons=0b101, buttons2=0b1)
    assert _until(lambda: len(got) == 1)
    value = got[0]
    assert [value.axis(a) for a in "xyzr"] == [0.5, -1.0, 1.0, 0.25]
    assert value.pressed(0) and value.pressed(2) and not value.pressed(1)
    assert value.pressed(16)  # buttons2 bit 0
    assert value.source_system == 255
    assert value.fields() == {
        "x": 500, "y": -1000, "z": 1000, "r": 250, "buttons": 0b101, "buttons2": 1, "target": 1
    }  # fmt: skip


def test_manual_control_feeds_the_ground_station_input_source(fake, make_link) -> None:
    from companion.config import PilotConfig
    from companion.inputs.manual_control import ManualControlInput

    source = ManualControlInput(PilotConfig(manual_override_button=1))
    link = make_link()
    link.on_manual_control(source.feed)  # the message reads as a mapping of its fields
    fake.send_manual_control(x=1000, y=-500, z=1000, r=0, buttons=0b10)
    assert _until(lambda: source.counts.messages == 1)
    human = source.read()
    assert human.override_held
    assert (human.command.pitch, human.command.roll, human.command.throttle) == (1.0, -0.5, 1.0)


def test_manual_control_out_of_range_is_dropped_and_counted(fake, make_link) -> None:
    link = make_link()
    got: list[ManualControlMessage] = []
    link.on_manual_control(got.append)
    fake.send_manual_control(x=1001)
    fake.send_manual_control(r=-20000)
    fake.send_manual_control(x=0, y=0, z=32767, r=0)  # INT16_MAX: axis not in use
    fake.send_manual_control(target=42)  # for another system: ignored
    assert _until(lambda: link.stats().manual_control_received == 4)
    assert link.stats().manual_control_dropped == 2
    assert len(got) == 1 and got[0].axis("z") is None and got[0].axis("x") == 0.0


def test_a_failing_callback_does_not_stop_the_link(fake, make_link) -> None:
    link = make_link()

    def broken(_value: ManualControlMessage) -> None:
        raise RuntimeError("consumer bug")

    link.on_manual_control(broken)
    fake.send_manual_control()
    assert _until(lambda: link.stats().callback_errors == 1)
    link.set_mode("OFFBOARD")  # the I/O thread still answers
    assert link.link_alive()


# ------------------------------------------------------------------ robustness
def test_garbage_datagrams_do_not_crash_the_link_thread(fake, make_link, rng) -> None:
    link = make_link()
    junk = [b"", b"\xfd", b"\xfe\x09" + b"\x00" * 3, b"\xfd" * 300]
    junk += [
        rng.integers(0, 256, size=int(n), dtype="uint8").tobytes() for n in rng.integers(1, 400, 30)
    ]
    for blob in junk:
        fake.send_garbage(blob)
    # a valid packet with a broken checksum
    good = fake.encoder.heartbeat_encode(2, 12, 0, 0, 4).pack(fake.encoder)
    fake.send_garbage(good[:-1] + bytes([good[-1] ^ 0xFF]))
    assert _until(lambda: link.stats().bad_data > 0)
    link.set_mode("OFFBOARD")
    assert _until(lambda: link.state().mode == "OFFBOARD")
    assert link.stats().thread_errors == 0


def test_snapshot_is_frozen_and_replaced_whole(fake, make_link) -> None:
    link = make_link()
    first = link.state()
    with pytest.raises(dataclasses.FrozenInstanceError):
        first.armed = True  # type: ignore[misc]
    assert _until(lambda: link.state() is not first)
    assert isinstance(link.state(), VehicleSnapshot)


# ------------------------------------------------------------------ tlog
def test_tlog_records_both_directions_and_pymavlink_reads_it(fake, make_link, tmp_path) -> None:
    path = tmp_path / "session.tlog"
    link = make_link(tlog_path=path)
    link.set_mode("OFFBOARD")
    link.send_velocity_body(VelocitySetpoint(1.0, 0.0, 0.0, 0.0))
    time.sleep(0.2)
    link.close()
    reader = mavutil.mavlink_connection(str(path))
    seen: list[tuple[str, int]] = []
    stamps: list[float] = []
    while (msg := reader.recv_match()) is not None:
        seen.append((msg.get_type(), msg.get_srcComponent()))
        stamps.append(msg._timestamp)
    assert ("HEARTBEAT", 191) in seen  # ours
    assert ("HEARTBEAT", 1) in seen  # the vehicle's
    assert ("SET_POSITION_TARGET_LOCAL_NED", 191) in seen
    assert ("COMMAND_ACK", 1) in seen
    assert stamps == sorted(stamps) and abs(stamps[-1] - time.time()) < 60
    # MAVProxy's direction bits in the raw records: 3 = sent by us, 0 = received
    raw, directions, offset = path.read_bytes(), {}, 0
    while offset < len(raw):
        usec = struct.unpack(">Q", raw[offset : offset + 8])[0]
        assert raw[offset + 8] == 0xFD  # MAVLink 2: magic, length, flags, seq, sys, comp
        length, signed, component = raw[offset + 9], raw[offset + 10] & 1, raw[offset + 14]
        directions.setdefault(component, set()).add(usec & 3)
        offset += 8 + 12 + length + (13 if signed else 0)
    assert directions[191] == {3} and directions[1] == {0}


# ------------------------------------------------------------------ contract
def test_pymavlink_link_meets_the_contract_against_the_fake(fake, make_link) -> None:
    names = run_link_contract(make_link())
    assert "arm_disarm" in names and "frames" in names


# ------------------------------------------------------------------ pure folding rules
def _encoder(system: int = 1, component: int = 1):
    return mavlink.MAVLink(None, srcSystem=system, srcComponent=component)


def _ardupilot_decoded(msg):  # type: ignore[no-untyped-def]
    """An ArduPilot-dialect message as the link parses it (the link speaks ardupilotmega)."""
    enc = ardupilotmega.MAVLink(None, srcSystem=1, srcComponent=1)
    return ardupilotmega.MAVLink(None).decode(bytearray(msg.pack(enc)))


def _decoded(msg, encoder):
    """A message as it arrives: packed and parsed, so source ids are set."""
    return mavlink.MAVLink(None).decode(bytearray(msg.pack(encoder)))


def test_telemetry_folds_into_a_new_snapshot_and_marks_frames() -> None:
    from companion.link.telemetry import apply_message, initial_snapshot

    enc = _encoder()
    beat = _decoded(enc.heartbeat_encode(2, 12, 0x81, px4_modes.custom_mode("AUTO.LAND"), 4), enc)
    first = initial_snapshot(beat, now_s=1.0)
    assert (first.autopilot, first.mode, first.armed) == ("PX4", "AUTO.LAND", True)
    pos = _decoded(enc.local_position_ned_encode(500, 1.0, 2.0, -3.0, 0.1, 0.2, 0.3), enc)
    after_pos = apply_message(first, pos, 2.0, "SYSTEM_TIME")
    assert after_pos is not first and first.position_valid is False
    assert after_pos.position_ned_m == (1.0, 2.0, -3.0) and after_pos.frame_time_boot_ms is None
    marker = _decoded(enc.system_time_encode(0, 600), enc)
    framed = apply_message(after_pos, marker, 3.0, "SYSTEM_TIME")
    assert (framed.frame_time_boot_ms, framed.time_boot_ms, framed.received_s) == (600, 600, 3.0)
    assert apply_message(first, pos, 2.0, "LOCAL_POSITION_NED").frame_time_boot_ms == 500
    landed = _decoded(enc.extended_sys_state_encode(0, 4), enc)
    assert apply_message(first, landed, 2.0, "SYSTEM_TIME").landed_state == "LANDING"


def test_each_message_changes_exactly_the_fields_its_handler_names() -> None:
    import dataclasses

    from companion.link.telemetry import HANDLERS, apply_message, initial_snapshot
    from companion.msg.snapshot import VehicleSnapshot

    enc = _encoder()
    beat = _decoded(enc.heartbeat_encode(2, 12, 0x81, px4_modes.custom_mode("OFFBOARD"), 4), enc)
    first = initial_snapshot(beat, now_s=1.0)
    messages = {
        "HEARTBEAT": beat,
        "LOCAL_POSITION_NED": _decoded(enc.local_position_ned_encode(500, 1.0, 2.0, -3.0, 0.1, 0.2, 0.3), enc),
        "ATTITUDE": _decoded(enc.attitude_encode(510, 0.1, -0.2, 0.3, 0.01, 0.02, 0.03), enc),
        "EXTENDED_SYS_STATE": _decoded(enc.extended_sys_state_encode(0, 2), enc),
        "SYSTEM_TIME": _decoded(enc.system_time_encode(0, 600), enc),
        "HOME_POSITION": _decoded(enc.home_position_encode(0, 0, 0, 0.0, 0.0, -0.7, [1, 0, 0, 0], 0, 0, 0), enc),
        "DISTANCE_SENSOR": _decoded(enc.distance_sensor_encode(0, 0, 10000, 48, 0, 0, 25, 0), enc),
        "HIL_STATE_QUATERNION": _decoded(enc.hil_state_quaternion_encode(0, [1, 0, 0, 0], 0, 0, 0, 473977486, 85455961,
                                                                          489267, 0, 0, 0, 0, 0, 0, 0, 0), enc),
        "SIMSTATE": _ardupilot_decoded(ardupilotmega.MAVLink_simstate_message(0, 0, 0, 0, 0, 0, 0, 0, 0, -353632621,
                                                                              1491652374)),
        "SIM_STATE": _ardupilot_decoded(ardupilotmega.MAVLink_sim_state_message(
            1, 0, 0, 0, 0, 0, 0, 0, 0, -9.8, 0, 0, 0, -353632621, 1491652374, 584.09, 0, 0, 0, 0, 0, -353632621, 1491652374)),
        "GPS_GLOBAL_ORIGIN": _decoded(enc.gps_global_origin_encode(473977486, 85455961, 488000), enc),
    }
    assert messages.keys() == HANDLERS.keys()
    names = {f.name for f in dataclasses.fields(VehicleSnapshot)}
    for kind, msg in messages.items():
        changes = HANDLERS[kind](msg, 2.0)
        assert changes.keys() <= names, kind
        got = apply_message(first, msg, 2.0, "SYSTEM_TIME")
        marker = {"frame_time_boot_ms": 600} if kind == "SYSTEM_TIME" else {}
        assert got == dataclasses.replace(first, **changes, **marker, received_s=2.0), kind
        assert type(got) is VehicleSnapshot and hash(got) == hash(dataclasses.replace(got))
        with pytest.raises(dataclasses.FrozenInstanceError):
            got.armed = False  # type: ignore[misc]


def test_heartbeats_of_cameras_and_ground_stations_do_not_change_the_vehicle_state() -> None:
    from companion.link.telemetry import apply_message, initial_snapshot, is_vehicle_heartbeat

    enc = _encoder()
    beat = _decoded(enc.heartbeat_encode(2, 12, 0, px4_modes.custom_mode("POSCTL"), 4), enc)
    snapshot = initial_snapshot(beat, 0.0)
    camera_enc = _encoder(1, 100)
    camera = _decoded(camera_enc.heartbeat_encode(30, 8, 0, 0, 4), camera_enc)
    gcs = _decoded(enc.heartbeat_encode(6, 8, 0, 0, 4), enc)
    assert is_vehicle_heartbeat(beat) and not is_vehicle_heartbeat(camera)
    assert not is_vehicle_heartbeat(gcs)
    assert apply_message(snapshot, camera, 1.0, "SYSTEM_TIME").mode == "POSCTL"


def test_manual_control_message_checks_itself() -> None:
    from companion.link.manual_control import ManualControlMessage

    with pytest.raises(ValueError, match="outside"):
        ManualControlMessage(0, 0, 1200, 0, 0, 1, 255, 190, 0.0)
    unused = ManualControlMessage(0, 0, 32767, 0, 1 << 31, 1, 255, 190, 0.0)
    assert unused.axis("z") is None and unused.pressed(31)
    assert unused.fields()["buttons2"] == 1 << 15
    assert unused["z"] == 32767 and unused.get("buttons2") == 1 << 15 and len(dict(unused)) == 7


# ------------------------------------------------------------------ against the real SITL
@pytest.mark.e2e
@pytest.mark.slow
@pytest.mark.timeout(60)
@pytest.mark.parametrize(
    ("kind", "clock"),
    [("pymavlink", "realtime"), ("pymavlink", "lockstep"), ("mavsdk", "realtime")],
)
def test_link_contract_against_the_sitl(kind: str, clock: str) -> None:
    import subprocess
    import sys

    port = free_udp_port()
    command = [sys.executable, "-m", "sitl", "--udp", f"0:{port}", "--tcp", "-1", "--no-camera",
               "--control-port", "0", "--clock", clock, "--duration", "120"]  # fmt: skip
    sitl = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        assert sitl.stdout is not None and sitl.stdout.readline().startswith("READY")
        cfg = LinkConfig(connection=f"udpin:127.0.0.1:{port}")
        with open_link(cfg, kind=kind) as link:  # type: ignore[arg-type]
            link.connect(timeout_s=10.0)
            assert "arm_disarm" in run_link_contract(link)
    finally:
        sitl.terminate()
        sitl.wait(timeout=10)


# ------------------------------------------------------------------ request_message (camera discovery)
CAMERA = 100  # MAV_COMP_ID_CAMERA


class FakeCamera:
    """A MAVLink camera component (system 1, component 100) beside the fake autopilot.

    It watches what the fake vehicle receives and answers REQUEST_MESSAGE addressed to
    component 100 through the vehicle's socket, as a camera on the vehicle's bus would.
    """

    def __init__(self, fake: FakeVehicle, uri: str, result: int = mavlink.MAV_RESULT_ACCEPTED) -> None:
        self.fake, self.uri, self.result = fake, uri, result
        self.mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=CAMERA)

    def answer_next(self, timeout_s: float = 2.0) -> None:
        request = self.fake.wait_for("COMMAND_LONG", timeout_s, lambda m: m.target_component == CAMERA
                                     and m.command == mavlink.MAV_CMD_REQUEST_MESSAGE)  # fmt: skip
        ack = mavlink.MAVLink_command_ack_message(request.command, self.result, 0, 0, 255, 0)
        replies = [ack]
        if self.result == mavlink.MAV_RESULT_ACCEPTED:
            replies.append(mavlink.MAVLink_video_stream_information_message(
                1, 1, mavlink.VIDEO_STREAM_TYPE_TCP_MPEG, 1, 10.0, 64, 48, 0, 0, 90, b"down",
                self.uri.encode()))  # fmt: skip
        self.fake.send_garbage(b"".join(m.pack(self.mav) for m in replies))  # raw bytes as comp 100

    def start(self) -> None:
        import threading

        threading.Thread(target=self.answer_next, daemon=True).start()


def test_request_message_returns_the_fields_the_component_sends(fake, make_link) -> None:
    link = make_link()
    FakeCamera(fake, "colf://127.0.0.1:5600").start()
    info = link.request_message("VIDEO_STREAM_INFORMATION", CAMERA, timeout_s=2.0)
    assert info is not None and info["uri"] == "colf://127.0.0.1:5600" and info["hfov"] == 90
    request = fake.commands(mavlink.MAV_CMD_REQUEST_MESSAGE)[0]
    assert (request.target_system, request.target_component) == (1, CAMERA)
    assert int(request.param1) == mavlink.MAVLINK_MSG_ID_VIDEO_STREAM_INFORMATION


def test_request_message_to_the_autopilot_returns_its_reply(fake, make_link) -> None:
    info = make_link().request_message("AUTOPILOT_VERSION", 1, timeout_s=2.0)
    assert info is not None and "flight_sw_version" in info and "mavpackettype" not in info


def test_request_message_without_such_component_gives_none_in_time(fake, make_link) -> None:
    link = make_link()  # the fake autopilot ACKs everything as component 1: not the camera's ACK
    t0 = time.monotonic()
    assert link.request_message("VIDEO_STREAM_INFORMATION", CAMERA, timeout_s=0.8) is None
    assert 0.7 < time.monotonic() - t0 < 1.5
    assert len(fake.commands(mavlink.MAV_CMD_REQUEST_MESSAGE)) >= 2  # resent, command_timeout_s=0.3


def test_request_message_refusal_raises_command_rejected(fake, make_link) -> None:
    link = make_link()
    FakeCamera(fake, "", result=mavlink.MAV_RESULT_DENIED).start()
    with pytest.raises(CommandRejected, match="DENIED"):
        link.request_message("VIDEO_STREAM_INFORMATION", CAMERA, timeout_s=2.0)
    with pytest.raises(CommandRejected, match="UNSUPPORTED"):
        link.request_message("CAMERA_INFORMATION", 1, timeout_s=2.0)  # the autopilot has none
    with pytest.raises(ValueError, match="unknown MAVLink message"):
        link.request_message("NO_SUCH_MESSAGE", 1)


def _video_file(path, frames: int = 20) -> str:
    """A small real video file (MJPG in AVI) that OpenCV can play back."""
    import cv2
    import numpy as np

    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 20.0, (64, 48))
    for i in range(frames):
        writer.write(np.full((48, 64, 3), 10 * i % 255, dtype=np.uint8))
    writer.release()
    return str(path)


def test_auto_camera_opens_the_stream_the_vehicle_advertises(fake, make_link, tmp_path) -> None:
    from companion.app import open_run_camera
    from companion.config import CompanionConfig

    link = make_link()
    FakeCamera(fake, _video_file(tmp_path / "down.avi")).start()
    camera = open_run_camera(CompanionConfig(), None, link)
    try:
        assert camera is not None and _until(lambda: camera.latest() is not None)
        assert camera.latest().image.shape == (48, 64, 3)  # type: ignore[union-attr]
    finally:
        if camera is not None:
            camera.close()


def test_auto_camera_without_a_camera_component_says_what_to_set(fake, make_link) -> None:
    from companion.app import open_run_camera
    from companion.config import CompanionConfig, PerceptionConfig
    from companion.errors import CameraError

    cfg = CompanionConfig(perception=PerceptionConfig(open_timeout_s=0.5))
    with pytest.raises(CameraError, match="advertised no video stream"):
        open_run_camera(cfg, None, make_link())


@pytest.fixture
def realtime_sitl() -> Iterator[tuple[object, int]]:
    from companion.simulator import start_sitl

    port = free_udp_port()
    sitl = start_sitl(port, clock="realtime", seed=5)
    yield sitl, port
    sitl.stop()


@pytest.mark.e2e
@pytest.mark.timeout(60)
def test_auto_camera_on_an_external_sitl_is_found_through_mavlink(realtime_sitl, tmp_path) -> None:
    """Connected as to any vehicle (RunOptions.connection): the camera comes from component 100."""
    import csv

    from companion.app import RunOptions, run_episodes
    from companion.config import load_companion_config

    sitl, port = realtime_sitl
    with MavlinkLink(LinkConfig(connection=f"udpin:127.0.0.1:{port}")) as link:
        link.connect(timeout_s=10.0)
        info = link.request_message("VIDEO_STREAM_INFORMATION", CAMERA, timeout_s=3.0)
    assert info is not None and info["uri"] == sitl.ports["camera_uri"]  # type: ignore[attr-defined]

    config = tmp_path / "short.toml"
    config.write_text("[companion.session]\nmax_steps = 3\nstart_tolerance_m = 50.0\n")
    opts = RunOptions(connection=f"udpin:127.0.0.1:{port}", pilot="expert", condition="demo", episodes=1,
                      run_dir=tmp_path / "run", config_path=config, learn=False,
                      simulator=f"127.0.0.1:{sitl.control_port}")  # type: ignore[attr-defined]
    result = run_episodes(load_companion_config(config), opts)
    assert result.records[0].steps == 3
    with (tmp_path / "run" / "human.csv").open(newline="") as f:
        rows = list(csv.DictReader(f))
    # a step on stale telemetry (a starved real-time SITL) is held, not recorded: every row is a true one
    assert 1 <= len(rows) == result.records[0].human_samples
    assert all(float(r["pad_radius"]) > 0 for r in rows)  # the camera saw the pad


@pytest.mark.e2e
@pytest.mark.timeout(60)
def test_mavsdk_request_message_finds_the_sitl_camera(realtime_sitl) -> None:
    sitl, port = realtime_sitl
    with open_link(LinkConfig(connection=f"udpin:127.0.0.1:{port}"), kind="mavsdk") as link:
        link.connect(timeout_s=10.0)
        info = link.request_message("VIDEO_STREAM_INFORMATION", CAMERA, timeout_s=3.0)
        assert info is not None and info["uri"] == sitl.ports["camera_uri"]  # type: ignore[attr-defined]
        assert link.request_message("VIDEO_STREAM_INFORMATION", 42, timeout_s=1.0) is None
        with pytest.raises(CommandRejected):
            link.request_message("MISSION_CURRENT", CAMERA, timeout_s=3.0)


def test_an_ardupilot_dialect_message_can_be_requested_and_asking_for_truth_never_stops_a_run(fake, make_link) -> None:
    from companion.link.truth import ask_for_truth

    link = make_link()
    assert link.request_rates({"SIMSTATE": 5.0})["SIMSTATE"] in ("ACCEPTED", "UNSUPPORTED", "DENIED", "FAILED", "TIMEOUT")
    assert fake.requested_intervals_us().get(164) == pytest.approx(200_000)  # SIMSTATE is ardupilotmega's
    ask_for_truth(link, "ARDUPILOTMEGA")  # the fake answers no GPS_GLOBAL_ORIGIN: logged, not raised
    ask_for_truth(link, "PX4")


def test_without_mavsdk_the_hint_installs_from_the_project(monkeypatch) -> None:
    """The distribution is not on a package index: the hint says ``pip install '.[mavsdk]'``."""
    import sys

    from companion.link import _require_mavsdk

    monkeypatch.setitem(sys.modules, "mavsdk", None)
    with pytest.raises(ConfigError, match=r"pip install '\.\[mavsdk\]'"):
        _require_mavsdk()


def test_the_link_is_lost_after_link_lost_s_of_silence_on_its_clock(caplog: pytest.LogCaptureFixture) -> None:
    """The logic the SIGKILL test (tests/reliability/test_killed.py) sees from outside, on a test
    clock: alive until ``link_lost_s`` after the last message, lost (once, with a warning) from
    then on, and back with the next message."""
    import logging

    from companion.link.mavlink_io import MavlinkIO

    now = [0.0]
    io = MavlinkIO(LinkConfig(link_lost_s=1.5), parse_connection("udpin:127.0.0.1:14540"), None, lambda: now[0])
    codec = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)

    def heartbeat():  # type: ignore[no-untyped-def]
        buf = codec.heartbeat_encode(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, 0, 0, 4).pack(codec)
        return codec.decode(bytearray(buf))

    assert not io.alive()  # nothing heard yet
    io._handle(heartbeat())
    with caplog.at_level(logging.WARNING, logger="companion.link.mavlink_io"):
        for t in (0.0, 1.0, 1.49):
            now[0] = t
            io._track_liveness()
            assert io.alive(), t
        for t in (1.5, 2.0, 30.0):
            now[0] = t
            io._track_liveness()
            assert not io.alive(), t
    assert io.counts["link_losses"] == 1
    assert [r.getMessage() for r in caplog.records] == ["MAVLink link lost: nothing heard for 1.5 s"]
    io._handle(heartbeat())
    assert io.alive() and io.counts["reconnections"] == 1
