"""The SITL's camera over real sockets: advertised by MAVLink, frame T before marker T."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from pymavlink.dialects.v20 import common as M

from companion.simulator import SimulatorClient, SitlProcess, start_sitl
from companion.vision.camera import open_camera
from companion.vision.perception import PadDetector
from tests.mav_client import MavTestClient

pytestmark = pytest.mark.e2e


@pytest.fixture
def sitl(client: MavTestClient) -> Iterator[SitlProcess]:
    s = start_sitl(client.port, clock="lockstep", camera=True)
    yield s
    s.stop()


def test_camera_component_advertises_the_stream(client: MavTestClient, sitl: SitlProcess) -> None:
    client.wait_for(lambda m: m.get_type() == "HEARTBEAT" and m.get_srcComponent() == M.MAV_COMP_ID_CAMERA)
    result = client.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_VIDEO_STREAM_INFORMATION,
                            target_component=M.MAV_COMP_ID_CAMERA)
    assert result == M.MAV_RESULT_ACCEPTED
    vsi = client.wait_for(lambda m: m.get_type() == "VIDEO_STREAM_INFORMATION")
    assert vsi.uri == sitl.ports["camera_uri"]
    assert (vsi.resolution_h, vsi.resolution_v) == (320, 240)
    assert client.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_CAMERA_INFORMATION,
                          target_component=M.MAV_COMP_ID_CAMERA) == M.MAV_RESULT_ACCEPTED
    info = client.wait_for(lambda m: m.get_type() == "CAMERA_INFORMATION")
    assert info.flags & M.CAMERA_CAP_FLAGS_HAS_VIDEO_STREAM


def test_lockstep_frame_of_step_t_arrives_before_its_marker_and_shows_the_pad(client: MavTestClient, sitl: SitlProcess) -> None:
    camera = open_camera(sitl.ports["camera_uri"])
    try:
        client.wait_for(lambda m: m.get_type() == "SYSTEM_TIME")
        ctl = SimulatorClient("127.0.0.1", sitl.control_port)
        reset = ctl.reset(seed=2)
        detector = PadDetector()
        seen = 0
        while seen < 10:
            marker = client.wait_for(lambda m: m.get_type() == "SYSTEM_TIME" and m.time_boot_ms > reset["time_boot_ms"], 5)
            frame = camera.frame_at(marker.time_boot_ms, timeout_s=0.5)  # written before the marker; decoded on a reader thread
            assert frame is not None and frame.time_boot_ms == marker.time_boot_ms
            assert detector.detect(frame.image) is not None  # the start keeps the pad in view
            client.body_velocity(0.0, echo_ms=marker.time_boot_ms)
            seen += 1
        ctl.close()
    finally:
        camera.close()
