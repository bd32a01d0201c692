"""The camera for ground stations: H.264 over RTP on UDP, as PX4's Gazebo simulation sends it
to QGroundControl (by default to UDP 5600 on the ground station's machine).

Frames are handed over without waiting (newest wins) and encoded on a thread of their own with
libx264 through PyAV (``ultrafast``, ``zerolatency``, a key frame every second with its SPS/PPS
repeated, so that a receiver that joins late starts within a second). Payload type 96, clock
90 kHz: :func:`sdp_for` gives the SDP a receiver such as FFmpeg or PyAV needs; QGroundControl's
UDP h.264 video source needs none.
"""

from __future__ import annotations

import logging
import threading
from fractions import Fraction

import numpy as np

log = logging.getLogger(__name__)
PAYLOAD_TYPE = 96


def parse_destination(text: str) -> tuple[str, int]:
    """``HOST:PORT`` -> (host, port); ValueError saying what is wrong."""
    host, sep, port = text.strip().rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ValueError(f"an RTP destination is HOST:PORT (e.g. 127.0.0.1:5600), got {text!r}")
    return host, int(port)


def sdp_for(host: str, port: int) -> str:
    """The session description of the stream as received at ``host:port``."""
    return (f"v=0\r\no=- 0 0 IN IP4 {host}\r\ns=col-sitl downward camera\r\nc=IN IP4 {host}\r\nt=0 0\r\n"
            f"m=video {port} RTP/AVP {PAYLOAD_TYPE}\r\na=rtpmap:{PAYLOAD_TYPE} H264/90000\r\n"
            "a=fmtp:96 packetization-mode=1\r\n")


class RtpVideoSender:
    """Encodes BGR frames to H.264 and sends them as RTP to ``destination`` (HOST:PORT)."""

    def __init__(self, destination: str, width_px: int, height_px: int, rate_hz: float) -> None:
        self.host, self.port = parse_destination(destination)
        self.width_px, self.height_px, self.rate_hz = width_px, height_px, rate_hz
        self.frames_sent = 0
        self.error: BaseException | None = None
        self._cond = threading.Condition()
        self._pending: np.ndarray | None = None
        self._closed = False
        self._thread = threading.Thread(target=self._run, name="rtp-video", daemon=True)
        self._thread.start()

    @property
    def uri(self) -> str:
        """How a MAVLink camera advertises such a stream (VIDEO_STREAM_INFORMATION)."""
        return f"udp://0.0.0.0:{self.port}"

    @property
    def alive(self) -> bool:
        return self.error is None and not self._closed

    def publish(self, image_bgr: np.ndarray) -> None:
        """Hand over one frame; an older one not yet encoded is dropped."""
        with self._cond:
            self._pending = image_bgr
            self._cond.notify()

    def close(self, timeout_s: float = 2.0) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify()
        self._thread.join(timeout_s)

    def _next(self) -> np.ndarray | None:
        with self._cond:
            self._cond.wait_for(lambda: self._closed or self._pending is not None)
            image, self._pending = self._pending, None
            return None if self._closed else image

    def _run(self) -> None:
        import av

        try:
            with av.open(f"rtp://{self.host}:{self.port}", mode="w", format="rtp") as container:
                stream = container.add_stream("libx264", rate=Fraction(self.rate_hz).limit_denominator(1000))
                stream.width, stream.height, stream.pix_fmt = self.width_px, self.height_px, "yuv420p"
                gop = max(1, round(self.rate_hz))
                stream.options = {"preset": "ultrafast", "tune": "zerolatency", "g": str(gop),
                                  "x264-params": f"repeat-headers=1:keyint={gop}"}
                while (image := self._next()) is not None:
                    frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(image), format="bgr24")
                    frame.pts = self.frames_sent
                    for packet in stream.encode(frame):
                        container.mux(packet)
                    self.frames_sent += 1
        except Exception as exc:  # the SITL flies on without its ground-station video
            self.error = exc
            log.error("RTP video to %s:%d stopped: %r", self.host, self.port, exc)
