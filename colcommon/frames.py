"""Camera frames and their wire format (docs/protocols.md, "Camera stream"): the message the
SITL's camera and the companion's cameras share, so neither side imports the other for it.

Each frame is a 32-byte little-endian header then the payload (raw BGR rows or JPEG):
magic ``b"COLF"``, version u16 = 1, encoding u16 (0 raw, 1 JPEG), frame_number u32,
time_boot_ms u32, width u16, height u16, payload_len u32, 8 reserved bytes (zero).
Anything that does not fit raises :class:`~colcommon.errors.CameraError` saying what was wrong,
so a reader can drop the connection and resynchronise by reconnecting.
"""

from __future__ import annotations

import struct
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
