"""Camera frames: the wire format, the server, and the companion's camera sources."""

from __future__ import annotations

import io
import logging
import socket
import struct
import threading

import cv2
import numpy as np
import pytest

from colcommon.frames import (
    HEADER_SIZE,
    Frame,
    decode_frame,
    decode_header,
    encode_frame,
    read_frame,
)
from companion.errors import CameraError
from companion.vision.camera import (
    OpenCVCameraSource,
    SitlCameraSource,
    open_camera,
    parse_colf_uri,
)
from sitl.frames import FrameServer
from tests.conftest import free_port, wait_until


def make_frame(rng: np.random.Generator, number: int = 3, stamp_ms: int = 1234, size=(24, 32)) -> Frame:
    return Frame(number, stamp_ms, rng.integers(0, 256, size=(*size, 3), dtype=np.uint8))




# ---- wire format -------------------------------------------------------------------------


def test_header_layout_matches_the_protocol(rng) -> None:
    data = encode_frame(make_frame(rng))
    magic, version, encoding, number, stamp, w, h, length, reserved = struct.unpack("<4sHHIIHHI8s", data[:32])
    assert HEADER_SIZE == 32
    assert (magic, version, encoding, number, stamp, w, h) == (b"COLF", 1, 0, 3, 1234, 32, 24)
    assert length == 32 * 24 * 3 == len(data) - 32 and reserved == bytes(8)


def test_raw_round_trip_is_exact(rng) -> None:
    frame = make_frame(rng)
    back = decode_frame(encode_frame(frame))
    assert (back.frame_number, back.time_boot_ms) == (3, 1234)
    np.testing.assert_array_equal(back.image, frame.image)


def test_jpeg_round_trip_is_close() -> None:
    image = np.zeros((48, 64, 3), np.uint8)
    cv2.circle(image, (32, 24), 15, (210, 40, 220), -1)
    data = encode_frame(Frame(0, 5, image), "jpeg")
    assert struct.unpack_from("<H", data, 6)[0] == 1
    back = decode_frame(data)
    assert back.image.shape == image.shape
    assert np.abs(back.image.astype(int) - image).mean() < 6  # chroma subsampling blurs the rim
    assert np.abs(back.image[24, 32].astype(int) - image[24, 32]).max() < 10


@pytest.mark.parametrize(
    ("offset", "value", "message"),
    [
        (0, b"XXXX", "magic"),
        (4, struct.pack("<H", 2), "version"),
        (6, struct.pack("<H", 7), "encoding"),
        (16, struct.pack("<H", 0), "empty"),
        (20, struct.pack("<I", 99), "does not fit"),
    ],
)
def test_corrupt_headers_raise_a_clear_error(rng, offset: int, value: bytes, message: str) -> None:
    data = bytearray(encode_frame(make_frame(rng)))
    data[offset:offset + len(value)] = value
    with pytest.raises(CameraError, match=message):
        decode_header(bytes(data[:32]))


def test_truncated_frames_raise_and_a_clean_end_is_none(rng) -> None:
    data = encode_frame(make_frame(rng))
    with pytest.raises(CameraError, match="truncated"):
        decode_header(data[:20])
    with pytest.raises(CameraError, match="truncated"):
        decode_frame(data[:-1])
    with pytest.raises(CameraError, match="truncated"):
        read_frame(io.BytesIO(data[:-10]))
    with pytest.raises(CameraError, match="truncated"):
        read_frame(io.BytesIO(data[:10]))
    stream = io.BytesIO(data + data)
    assert read_frame(stream) is not None and read_frame(stream) is not None
    assert read_frame(stream) is None


def test_corrupt_jpeg_payload_raises(rng) -> None:
    data = bytearray(encode_frame(make_frame(rng), "jpeg"))
    data[32:] = bytes(len(data) - 32)
    with pytest.raises(CameraError, match="JPEG"):
        decode_frame(bytes(data))


def test_frame_validates_itself(rng) -> None:
    with pytest.raises(ValueError, match="uint8"):
        Frame(0, 0, np.zeros((4, 4, 3), np.float32))
    with pytest.raises(ValueError, match="u32"):
        Frame(-1, 0, np.zeros((4, 4, 3), np.uint8))


# ---- server and SITL source over loopback TCP ----------------------------------------------


def test_lockstep_frames_arrive_before_publish_returns(rng) -> None:
    with FrameServer() as server:
        assert server.uri == f"colf://127.0.0.1:{server.port}"
        source = SitlCameraSource(server.uri)
        source.open()
        try:
            assert wait_until(lambda: server.client_count == 1)
            for k in range(5):
                frame = make_frame(rng, number=k, stamp_ms=100 * k)
                server.publish(frame, blocking=True)
                got = source.frame_at(100 * k, timeout_s=2.0)
                assert got is not None and got.frame_number == k
                np.testing.assert_array_equal(got.image, frame.image)
            assert source.frame_at(10_000, timeout_s=0.05) is None  # not yet rendered
        finally:
            source.close()


def test_jpeg_stream_and_open_camera(rng) -> None:
    with FrameServer(encoding="jpeg") as server:
        source = open_camera(server.uri)
        try:
            assert wait_until(lambda: server.client_count == 1)
            server.publish(Frame(0, 50, np.full((24, 32, 3), 90, np.uint8)), blocking=True)
            got = source.frame_at(50, 2.0)
            assert got is not None and abs(int(got.image.mean()) - 90) <= 2
        finally:
            source.close()


class StalledSocket:
    """A reader's socket that never takes a byte until released; then the write times out, as
    a socket with ``write_timeout_s`` does for a reader that stopped reading."""

    def __init__(self) -> None:
        self.release = threading.Event()
        self.writes = 0

    def sendall(self, data: bytes) -> None:
        self.writes += 1
        self.release.wait()
        raise TimeoutError("timed out")

    def shutdown(self, how: int) -> None:
        self.release.set()

    def close(self) -> None:
        self.release.set()


def in_thread(work, timeout_s: float = 30.0) -> bool:  # type: ignore[no-untyped-def]
    """Run ``work`` in a thread; True if it finished (a generous limit: only a hang fails it)."""
    thread = threading.Thread(target=work, daemon=True)
    thread.start()
    thread.join(timeout_s)
    return not thread.is_alive()


def test_a_reader_that_never_reads_never_stalls_real_time(rng) -> None:
    """Non-blocking publish only fills the reader's one-frame mailbox: with its writer stuck in
    a send, 100 more publishes all return and the newest frame is the one waiting; when the write
    times out the reader is dropped. (How long a publish takes is bench/ material.)"""
    with FrameServer(write_timeout_s=0.3) as server:
        reader = socket.create_connection(("127.0.0.1", server.port))
        try:
            assert wait_until(lambda: server.client_count == 1)
            (client,) = server._clients
            stalled = StalledSocket()
            real, client.sock = client.sock, stalled  # type: ignore[assignment]
            server.publish(make_frame(rng, number=0), blocking=False)
            assert wait_until(lambda: stalled.writes == 1)  # the writer took frame 0 and is stuck in the send
            assert in_thread(lambda: [server.publish(make_frame(rng, number=k), blocking=False) for k in range(1, 101)])
            assert stalled.writes == 1 and client._pending is not None
            assert decode_frame(client._pending).frame_number == 100  # the newest waits; the others were skipped
            stalled.release.set()
            assert wait_until(lambda: server.client_count == 0), "stalled reader was not dropped"
            real.close()
        finally:
            reader.close()


def test_blocking_publish_gives_up_on_a_stalled_reader(rng) -> None:
    """Lockstep publish waits for the reader, but not for ever: a reader that stopped reading
    is dropped and the publishes go on (here on a real socket whose buffers fill up)."""
    with FrameServer(write_timeout_s=0.3) as server:
        stuck = socket.create_connection(("127.0.0.1", server.port))
        try:
            assert wait_until(lambda: server.client_count == 1)
            big = make_frame(rng, size=(480, 640))
            assert in_thread(lambda: [server.publish(big, blocking=True) for _ in range(30)])
            assert server.client_count == 0
        finally:
            stuck.close()


def test_source_that_disappears_gives_none_and_a_warning(rng, caplog) -> None:
    server = FrameServer()
    source = SitlCameraSource(server.uri, reconnect_s=0.05)
    source.open()
    try:
        assert wait_until(lambda: server.client_count == 1)
        server.publish(make_frame(rng, stamp_ms=10), blocking=True)
        assert source.frame_at(10, 2.0) is not None
        with caplog.at_level(logging.WARNING, logger="companion.vision.camera"):
            server.close()
            assert wait_until(lambda: source.latest() is None)
            assert source.frame_at(20, timeout_s=0.1) is None
        assert any("camera" in r.getMessage() and r.levelno == logging.WARNING for r in caplog.records)
    finally:
        source.close()
        server.close()


def test_source_reconnects_when_the_sitl_comes_back(rng) -> None:
    port = free_port(socket.SOCK_STREAM)
    first = FrameServer(port=port)
    source = SitlCameraSource(first.uri, reconnect_s=0.05)
    source.open()
    try:
        assert wait_until(lambda: first.client_count == 1)
        first.close()
        assert wait_until(lambda: source.latest() is None)
        with FrameServer(port=port) as second:
            assert wait_until(lambda: second.client_count == 1)
            second.publish(make_frame(rng, stamp_ms=77), blocking=True)
            assert source.frame_at(77, 2.0) is not None
    finally:
        source.close()


def test_corrupt_stream_drops_the_connection_with_a_warning(rng, caplog) -> None:
    listener = socket.create_server(("127.0.0.1", 0))
    source = SitlCameraSource(f"colf://127.0.0.1:{listener.getsockname()[1]}", reconnect_s=10.0)
    try:
        source.open()
        conn, _ = listener.accept()
        with caplog.at_level(logging.WARNING, logger="companion.vision.camera"):
            conn.sendall(b"NOPE" + bytes(28))
            assert wait_until(lambda: any("magic" in r.getMessage() for r in caplog.records))
        assert source.latest() is None
        conn.close()
    finally:
        source.close()
        listener.close()


# ---- opening sources -----------------------------------------------------------------------


def test_missing_sources_fail_at_start_with_a_clear_error(tmp_path) -> None:
    port = free_port(socket.SOCK_STREAM)
    with pytest.raises(CameraError, match="Is the SITL running"):
        open_camera(f"colf://127.0.0.1:{port}", open_timeout_s=0.5)
    with pytest.raises(CameraError, match="advertised no video stream"):
        open_camera("auto")
    with pytest.raises(CameraError, match="neither"):
        open_camera(str(tmp_path / "missing.avi"))
    with pytest.raises(CameraError, match="colf://host:port"):
        parse_colf_uri("colf://nohost")


def test_auto_uses_the_advertised_stream(rng) -> None:
    """"auto" opens the stream the vehicle advertised: the frames published there arrive."""
    with FrameServer() as server:
        source = open_camera("auto", auto_uri=server.uri)
        try:
            assert isinstance(source, SitlCameraSource)
            assert wait_until(lambda: server.client_count == 1)
            server.publish(make_frame(rng, stamp_ms=420), blocking=True)
            got = source.frame_at(420, 5.0)
            assert got is not None and got.time_boot_ms == 420
        finally:
            source.close()


def write_video(path, frames: int, size=(64, 48)) -> None:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 50.0, size)
    assert writer.isOpened(), "OpenCV cannot write MJPG here"
    for k in range(frames):
        writer.write(np.full((size[1], size[0], 3), 20 * k, np.uint8))
    writer.release()


def test_opencv_file_source_plays_then_goes_dead(tmp_path, caplog) -> None:
    path = tmp_path / "clip.avi"
    write_video(path, 5)
    source = open_camera(str(path))
    assert isinstance(source, OpenCVCameraSource)
    try:
        first = source.latest()
        assert first is not None and first.image.shape == (48, 64, 3)
        with caplog.at_level(logging.WARNING, logger="companion.vision.camera"):
            assert wait_until(lambda: source.latest() is None, 3.0)  # 5 frames at 50 fps, then the end
            # the reader thread marks the source dead, then logs why: wait for the line too (a CI run
            # at load 8 read the records between the two)
            assert wait_until(lambda: any("end of file" in r.getMessage() for r in caplog.records), 3.0)
    finally:
        source.close()


def test_opencv_source_refuses_an_unreadable_file(tmp_path) -> None:
    path = tmp_path / "not_a_video.avi"
    path.write_bytes(b"garbage" * 10)
    with pytest.raises(CameraError, match="camera"):
        open_camera(str(path))


def test_rendered_frame_over_the_wire_gives_the_observation() -> None:
    """The whole camera path: render, serve, receive, detect, build the observation vector."""
    from companion.msg.observation import Observation
    from companion.vision.perception import PadDetector
    from sitl.camera import CameraRenderer
    from sitl.config import CameraConfig, WorldConfig
    from sitl.world import World

    renderer = CameraRenderer(CameraConfig(), World(WorldConfig()))
    camera_ned = renderer.world.pad_ned(0.0) + [1.0, 0.0, -4.0]  # pad 1 m south -> 40 px down
    with FrameServer() as server:
        source = open_camera(server.uri)
        try:
            assert wait_until(lambda: server.client_count == 1)
            server.publish(Frame(0, 2000, renderer.render(camera_ned, [0, 0, 0], 2.0)), blocking=True)
            frame = source.frame_at(2000, 2.0)
        finally:
            source.close()
    assert frame is not None
    pad = PadDetector().detect(frame.image)
    assert pad is not None and (pad.u_px, pad.v_px) == pytest.approx((159.5, 159.5), abs=0.5)
    obs = Observation(camera_ned, (0, 0, 0), (0, 0, 0), (0, 0, 0), pad, frame.size_px, frame.time_boot_ms)
    vec = obs.to_vector()
    assert vec[12:14] == pytest.approx([0.0, 40 / 120], abs=0.01)
    assert vec[14] == pytest.approx(20 / 120, rel=0.05)  # 160 px * 0.5 m / 4 m = 20 px
