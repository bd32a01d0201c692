"""The SITL's camera for ground stations: H.264 over RTP on UDP, advertised as stream 2 of
VIDEO_STREAM_INFORMATION, decoded here by a real decoder (FFmpeg through PyAV) in which the
pad detector finds the pad."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as M

from companion.simulator import SimulatorClient, SitlProcess, start_sitl
from companion.vision.perception import PadDetector
from sitl.rtp import parse_destination, sdp_for
from tests.conftest import free_rtp_port
from tests.mav_client import MavTestClient

pytestmark = [pytest.mark.realtime, pytest.mark.e2e, pytest.mark.timeout(120)]
av = pytest.importorskip("av")


def test_destinations_are_checked() -> None:
    assert parse_destination("127.0.0.1:5600") == ("127.0.0.1", 5600)
    for bad in ("5600", "host:", ":5600", "host:70000", "host:port"):
        with pytest.raises(ValueError, match="HOST:PORT"):
            parse_destination(bad)


@pytest.fixture
def rtp_sitl(client: MavTestClient) -> Iterator[tuple[SitlProcess, int]]:
    port = free_rtp_port()
    s = start_sitl(client.port, clock="realtime", extra_args=["--rtp", f"127.0.0.1:{port}", "--camera-rate", "20"])
    yield s, port
    s.stop()


def receive(sdp: Path, frames: list[np.ndarray], stop: threading.Event, want: int) -> None:
    with av.open(str(sdp), format="sdp", options={"protocol_whitelist": "file,udp,rtp", "timeout": "10000000"}) as c:
        for frame in c.decode(video=0):
            frames.append(frame.to_ndarray(format="bgr24"))
            if len(frames) >= want or stop.is_set():
                return


def test_ground_stations_get_h264_over_rtp_showing_the_pad(client: MavTestClient, rtp_sitl, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    sitl, port = rtp_sitl
    client.wait_for(lambda m: m.get_type() == "HEARTBEAT" and m.get_srcComponent() == M.MAV_COMP_ID_CAMERA)
    assert client.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_VIDEO_STREAM_INFORMATION, 2,
                          target_component=M.MAV_COMP_ID_CAMERA) == M.MAV_RESULT_ACCEPTED
    vsi = client.wait_for(lambda m: m.get_type() == "VIDEO_STREAM_INFORMATION")
    assert (vsi.stream_id, vsi.count, vsi.type, vsi.encoding) == (2, 2, M.VIDEO_STREAM_TYPE_RTPUDP, M.VIDEO_STREAM_ENCODING_H264)
    assert vsi.uri == f"udp://0.0.0.0:{port}"

    ctl = SimulatorClient("127.0.0.1", sitl.control_port)
    try:
        ctl.reset(seed=2)  # 8 m above the pad, which is in view
    finally:
        ctl.close()
    sdp = tmp_path / "stream.sdp"
    sdp.write_text(sdp_for("127.0.0.1", port))
    frames: list[np.ndarray] = []
    stop = threading.Event()
    reader = threading.Thread(target=receive, args=(sdp, frames, stop, 40), daemon=True)
    reader.start()
    reader.join(60)
    stop.set()
    assert len(frames) >= 20, f"decoded only {len(frames)} frames"
    assert frames[-1].shape == (240, 320, 3)
    detector = PadDetector()
    found = [d for d in (detector.detect(f) for f in frames[-10:]) if d is not None]
    assert len(found) >= 8, "the pad is not found in the decoded frames"
    assert all(abs(d.radius_px - found[0].radius_px) < 3 for d in found)
