"""Camera frames on the wire (docs/protocols.md, "Camera stream"), shared by server and client.

Each frame is a 32-byte little-endian header then the payload (raw BGR rows or JPEG):
magic ``b"COLF"``, version u16 = 1, encoding u16 (0 raw, 1 JPEG), frame_number u32,
time_boot_ms u32, width u16, height u16, payload_len u32, 8 reserved bytes (zero).
Anything that does not fit raises :class:`~colcommon.errors.CameraError` saying what was wrong,
so a reader can drop the connection and resynchronise by reconnecting.
"""

from __future__ import annotations

import contextlib
import socket
import struct
import threading
from dataclasses import dataclass
from typing import BinaryIO

import cv2
import numpy as np

from colcommon.errors import CameraError

MAGIC = b"COLF"
VERSION = 1
HEADER = struct.Struct("<4sHHIIHHI8s")
HEADER_SIZE = HEADER.size  # 32
ENCODINGS = {"raw": 0, "jpeg": 1}
MAX_PAYLOAD_BYTES = 64 * 1024 * 1024  # a 4096x4096 raw frame is 48 MiB
_U32 = 2**32


@dataclass(frozen=True)
class Frame:
    """One camera image (BGR uint8, HxWx3) stamped with the time of the pose it shows."""

    frame_number: int
    time_boot_ms: int
    image: np.ndarray

    def __post_init__(self) -> None:
        img = self.image
        if not (isinstance(img, np.ndarray) and img.dtype == np.uint8 and img.ndim == 3 and img.shape[2] == 3):
            raise ValueError(f"frame image must be HxWx3 uint8 BGR, got {getattr(img, 'shape', type(img))}")
        if not (0 < img.shape[0] < 65536 and 0 < img.shape[1] < 65536):
            raise ValueError(f"frame size {img.shape[1]}x{img.shape[0]} does not fit the u16 header fields")
        for name in ("frame_number", "time_boot_ms"):
            value = getattr(self, name)
            if not 0 <= value < _U32:
                raise ValueError(f"{name} must fit in u32, got {value}")

    @property
    def size_px(self) -> tuple[int, int]:
        """(width, height)."""
        return int(self.image.shape[1]), int(self.image.shape[0])


@dataclass(frozen=True)
class FrameHeader:
    encoding: int
    frame_number: int
    time_boot_ms: int
    width: int
    height: int
    payload_len: int


def encode_frame(frame: Frame, encoding: str = "raw", jpeg_quality: int = 90) -> bytes:
    """Header + payload, ready for ``sendall``. Stamps wrap modulo 2**32 like MAVLink's."""
    if encoding not in ENCODINGS:
        raise ValueError(f"encoding must be one of {sorted(ENCODINGS)}, got {encoding!r}")
    if encoding == "raw":
        payload = np.ascontiguousarray(frame.image).tobytes()
    else:
        ok, buf = cv2.imencode(".jpg", frame.image, [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)])
        if not ok:
            raise CameraError("JPEG encoding of a camera frame failed; use encoding='raw'")
        payload = buf.tobytes()
    width, height = frame.size_px
    header = HEADER.pack(
        MAGIC, VERSION, ENCODINGS[encoding], frame.frame_number, frame.time_boot_ms,
        width, height, len(payload), bytes(8),
    )
    return header + payload


def decode_header(data: bytes) -> FrameHeader:
    """Parse and check the 32-byte header."""
    if len(data) != HEADER_SIZE:
        raise CameraError(f"frame header is {len(data)} bytes, expected {HEADER_SIZE}: truncated stream")
    magic, version, encoding, number, stamp, width, height, length, _reserved = HEADER.unpack(data)
    if magic != MAGIC:
        raise CameraError(f"bad frame magic {magic!r} (expected {MAGIC!r}): not a COLF camera stream, or out of sync")
    if version != VERSION:
        raise CameraError(f"camera stream version {version}, this reader knows {VERSION}: update the companion or the SITL")
    if encoding not in ENCODINGS.values():
        raise CameraError(f"unknown frame encoding {encoding} (0 raw, 1 JPEG)")
    if width == 0 or height == 0:
        raise CameraError(f"frame size {width}x{height} is empty: corrupt header")
    if length > MAX_PAYLOAD_BYTES or (encoding == 0 and length != width * height * 3):
        raise CameraError(f"frame payload of {length} bytes does not fit a {width}x{height} frame: corrupt header")
    return FrameHeader(encoding, number, stamp, width, height, length)


def decode_payload(header: FrameHeader, payload: bytes) -> Frame:
    """The frame a header and its payload describe."""
    if len(payload) != header.payload_len:
        raise CameraError(f"frame payload is {len(payload)} bytes, header says {header.payload_len}: truncated")
    shape = (header.height, header.width, 3)
    if header.encoding == 0:
        return Frame(header.frame_number, header.time_boot_ms, np.frombuffer(payload, np.uint8).reshape(shape).copy())
    decoded = cv2.imdecode(np.frombuffer(payload, np.uint8), cv2.IMREAD_COLOR)
    if decoded is None or decoded.shape != shape:
        raise CameraError(f"JPEG payload of frame {header.frame_number} does not decode to {header.width}x{header.height}")
    return Frame(header.frame_number, header.time_boot_ms, np.asarray(decoded, np.uint8))


def decode_frame(data: bytes) -> Frame:
    """One whole encoded frame (header + payload, nothing more)."""
    header = decode_header(bytes(data[:HEADER_SIZE]))
    return decode_payload(header, bytes(data[HEADER_SIZE:]))


def read_frame(stream: BinaryIO) -> Frame | None:
    """The next frame from a binary stream; None at a clean end (between frames)."""
    head = _read_exact(stream, HEADER_SIZE, allow_eof=True)
    if head is None:
        return None
    header = decode_header(head)
    payload = _read_exact(stream, header.payload_len, allow_eof=False)
    assert payload is not None
    return decode_payload(header, payload)


def _read_exact(stream: BinaryIO, n: int, allow_eof: bool) -> bytes | None:
    chunks, remaining = [], n
    while remaining:
        chunk = stream.read(remaining)
        if not chunk:
            if allow_eof and remaining == n:
                return None
            raise CameraError(f"camera stream ended inside a frame ({n - remaining} of {n} bytes): truncated")
        chunks.append(chunk)
        remaining -= len(chunk)
    return b"".join(chunks)


class _Client:
    """One connected reader with its own writer thread and a one-frame mailbox (newest wins)."""

    def __init__(self, sock: socket.socket, write_timeout_s: float) -> None:
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        sock.settimeout(write_timeout_s)
        self.sock = sock
        self.alive = True
        self._cond = threading.Condition()
        self._pending: bytes | None = None
        self._pending_seq = 0
        self._sent_seq = 0
        self._thread = threading.Thread(target=self._run, name="colf-writer", daemon=True)
        self._thread.start()

    def offer(self, data: bytes, seq: int) -> None:
        with self._cond:
            self._pending, self._pending_seq = data, seq
            self._cond.notify_all()

    def wait_sent(self, seq: int, timeout_s: float) -> bool:
        """True once frame ``seq`` (or a newer one) is completely written."""
        with self._cond:
            self._cond.wait_for(lambda: self._sent_seq >= seq or not self.alive, timeout_s)
            return self._sent_seq >= seq

    def close(self) -> None:
        with self._cond:
            self.alive = False
            self._cond.notify_all()
        with contextlib.suppress(OSError):
            self.sock.shutdown(socket.SHUT_RDWR)
        self.sock.close()

    def join(self, timeout_s: float) -> None:
        self._thread.join(timeout_s)

    def _run(self) -> None:
        while True:
            with self._cond:
                self._cond.wait_for(lambda: self._pending is not None or not self.alive)
                if not self.alive:
                    return
                data, seq, self._pending = self._pending, self._pending_seq, None
            assert data is not None
            try:
                self.sock.sendall(data)
            except OSError:  # reader gone, or too slow for write_timeout_s: the stream is broken
                self.close()
                return
            with self._cond:
                self._sent_seq = seq
                self._cond.notify_all()


class FrameServer:
    """Serves camera frames to any number of TCP readers on loopback (``colf://host:port``).

    ``publish(frame, blocking=True)`` (lockstep) returns once every reader has the whole frame;
    a reader that takes longer than ``write_timeout_s`` is dropped so the simulation never hangs.
    ``blocking=False`` (real time) only hands the frame to each reader's writer thread: a slow
    reader skips frames and never stalls the caller. Dead readers are removed.
    """

    def __init__(
        self, host: str = "127.0.0.1", port: int = 0, encoding: str = "raw",
        jpeg_quality: int = 90, write_timeout_s: float = 2.0,
    ) -> None:
        if encoding not in ENCODINGS:
            raise ValueError(f"encoding must be one of {sorted(ENCODINGS)}, got {encoding!r}")
        self.encoding, self.jpeg_quality, self.write_timeout_s = encoding, jpeg_quality, write_timeout_s
        self._listener = socket.create_server((host, port))
        self._listener.settimeout(0.1)
        self.host = host
        self.port: int = self._listener.getsockname()[1]
        self._clients: list[_Client] = []
        self._lock = threading.Lock()
        self._closed = threading.Event()
        self._seq = 0
        self._accept_thread = threading.Thread(target=self._accept_loop, name="colf-accept", daemon=True)
        self._accept_thread.start()

    @property
    def uri(self) -> str:
        return f"colf://{self.host}:{self.port}"

    @property
    def client_count(self) -> int:
        with self._lock:
            return sum(c.alive for c in self._clients)

    def publish(self, frame: Frame, blocking: bool) -> None:
        """Send ``frame`` to every connected reader (see the class docstring)."""
        with self._lock:
            self._clients = [c for c in self._clients if c.alive]
            clients = list(self._clients)
        if not clients:
            return
        data = encode_frame(frame, self.encoding, self.jpeg_quality)
        self._seq += 1
        for client in clients:
            client.offer(data, self._seq)
        if blocking:
            for client in clients:
                if not client.wait_sent(self._seq, self.write_timeout_s):
                    client.close()

    def close(self) -> None:
        """Stop accepting, disconnect every reader and join the threads."""
        self._closed.set()
        self._accept_thread.join(1.0)
        self._listener.close()
        with self._lock:
            clients, self._clients = self._clients, []
        for client in clients:
            client.close()
            client.join(1.0)

    def __enter__(self) -> FrameServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _accept_loop(self) -> None:
        while not self._closed.is_set():
            try:
                sock, _ = self._listener.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            client = _Client(sock, self.write_timeout_s)
            with self._lock:
                if self._closed.is_set():
                    client.close()
                    return
                self._clients.append(client)
