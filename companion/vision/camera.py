"""Camera sources behind one interface: the SITL's frame stream and OpenCV capture.

A source reads frames on its own thread and keeps only the newest, so the control loop never
waits on a camera it does not need. Failing to open is a :class:`CameraError` at start, with
what to check; once running, a source that dies makes ``latest()`` and ``frame_at()`` return
None (the observation then says "pad not visible") and logs a warning, never raises.
The SITL source keeps trying to reconnect; an OpenCV source that ends stays dead.
"""

from __future__ import annotations

import contextlib
import logging
import os
import socket
import threading
import time
from collections.abc import Callable
from typing import Any, Protocol

import cv2
import numpy as np

from colcommon.frames import Frame, read_frame
from companion.errors import CameraError

log = logging.getLogger(__name__)
SITL_SCHEME = "colf://"
LOCKSTEP_FRAME_PATIENCE_S = 10.0
"""How long a lockstep step waits for its own frame at least. The SITL writes a frame's image
whole before the frame's marker, so once the marker is in, the image is on its way: waiting costs
nothing on a healthy machine, and on a starved one it keeps the step's true picture instead of
flying it blind (a camera that drops or dies ends the wait at once). As long as the SITL waits
for an answer at most (``[sitl.clock] lockstep_timeout_s``)."""


class CameraSource(Protocol):
    """What the companion needs from a camera."""

    def open(self) -> None: ...

    def latest(self) -> Frame | None: ...

    def frame_at(self, time_boot_ms: int, timeout_s: float) -> Frame | None: ...

    def close(self) -> None: ...


def lockstep_frame(camera: CameraSource, time_boot_ms: int, timeout_s: float) -> Frame | None:
    """The frame of the lockstep step stamped ``time_boot_ms``: ``timeout_s`` or
    :data:`LOCKSTEP_FRAME_PATIENCE_S`, whichever is longer."""
    return camera.frame_at(time_boot_ms, max(timeout_s, LOCKSTEP_FRAME_PATIENCE_S))


class _FrameSlot:
    """The newest frame and the source's health, shared by the reader thread and the caller."""

    def __init__(self, name: str, warn_every_s: float = 5.0) -> None:
        self.name = name
        self._cond = threading.Condition()
        self._frame: Frame | None = None
        self._dead_reason: str | None = None
        self._warn_every_s = warn_every_s
        self._last_warning = -float("inf")

    def put(self, frame: Frame) -> None:
        with self._cond:
            if self._dead_reason is not None:
                log.info("camera %s delivers frames again", self.name)
            self._frame, self._dead_reason = frame, None
            self._cond.notify_all()

    def revive(self) -> None:
        """The source is back (connected again) though no frame has arrived yet."""
        with self._cond:
            if self._dead_reason is not None:
                log.info("camera %s reconnected", self.name)
            self._dead_reason = None
            self._cond.notify_all()

    def mark_dead(self, reason: str) -> None:
        with self._cond:
            self._dead_reason, self._frame = reason, None
            self._cond.notify_all()
        self.warn(f"camera {self.name} lost: {reason}")

    def latest(self) -> Frame | None:
        with self._cond:
            frame, reason = self._frame, self._dead_reason
        if reason is not None:
            self.warn(f"camera {self.name} is down ({reason}); the pad counts as not visible")
        return frame

    def wait(self, time_boot_ms: int, timeout_s: float) -> Frame | None:
        """The newest frame stamped at or after ``time_boot_ms``, waiting up to ``timeout_s``."""
        def ready() -> bool:
            f = self._frame
            return self._dead_reason is not None or (f is not None and f.time_boot_ms >= time_boot_ms)

        with self._cond:
            self._cond.wait_for(ready, max(timeout_s, 0.0))
            frame, reason = self._frame, self._dead_reason
        if reason is not None or frame is None or frame.time_boot_ms < time_boot_ms:
            why = reason or f"no frame stamped >= {time_boot_ms} ms within {timeout_s:.3f} s"
            self.warn(f"camera {self.name}: {why}; the pad counts as not visible")
            return None
        return frame

    def warn(self, message: str) -> None:
        """Log at most one warning per ``warn_every_s``, so a dead camera does not flood the log."""
        now = time.monotonic()
        if now - self._last_warning >= self._warn_every_s:
            self._last_warning = now
            log.warning(message)


class _ReaderSource:
    """A source whose reader thread puts frames into a :class:`_FrameSlot` the caller reads."""

    def __init__(self, name: str) -> None:
        self._slot = _FrameSlot(name)
        self._closed = threading.Event()
        self._thread: threading.Thread | None = None

    def latest(self) -> Frame | None:
        return self._slot.latest()

    def frame_at(self, time_boot_ms: int, timeout_s: float) -> Frame | None:
        return self._slot.wait(time_boot_ms, timeout_s)

    def _start_reader(self, name: str, run: Callable[..., None], *args: Any) -> None:
        self._thread = threading.Thread(target=run, args=args, name=name, daemon=True)
        self._thread.start()


class SitlCameraSource(_ReaderSource):
    """Reads a ``colf://host:port`` stream (the SITL's camera) and reconnects if it drops."""

    vehicle_time_stamps = True  # frames carry the simulation's time_boot_ms of their pose

    def __init__(self, uri: str, connect_timeout_s: float = 3.0, reconnect_s: float = 0.5) -> None:
        self.uri = uri
        self.host, self.port = parse_colf_uri(uri)
        self.connect_timeout_s, self.reconnect_s = connect_timeout_s, reconnect_s
        super().__init__(uri)
        self._sock: socket.socket | None = None

    def open(self) -> None:
        try:
            sock = self._connect()
        except OSError as exc:
            raise CameraError(
                f"cannot connect to camera stream {self.uri}: {exc}. Is the SITL running with "
                "[sitl.camera] enabled = true, and is this its camera_port?"
            ) from exc
        self._start_reader("colf-reader", self._run, sock)

    def close(self) -> None:
        self._closed.set()
        self._shutdown_socket()
        if self._thread is not None:
            self._thread.join(2.0)

    def _connect(self) -> socket.socket:
        sock = socket.create_connection((self.host, self.port), timeout=self.connect_timeout_s)
        sock.settimeout(None)  # the reader blocks; close() unblocks it with shutdown()
        self._sock = sock
        return sock

    def _shutdown_socket(self) -> None:
        sock, self._sock = self._sock, None
        if sock is not None:
            with contextlib.suppress(OSError):
                sock.shutdown(socket.SHUT_RDWR)
            sock.close()

    def _run(self, sock: socket.socket | None) -> None:
        while not self._closed.is_set():
            if sock is None:
                sock = self._reconnect()
                continue
            reason = self._read_until_error(sock)
            self._shutdown_socket()
            sock = None
            if not self._closed.is_set():
                self._slot.mark_dead(reason)
        self._shutdown_socket()  # a reconnect may have raced with close()

    def _read_until_error(self, sock: socket.socket) -> str:
        stream = sock.makefile("rb")
        try:
            while not self._closed.is_set():
                frame = read_frame(stream)
                if frame is None:
                    return "the SITL closed the stream"
                self._slot.put(frame)
        except (CameraError, OSError, ValueError) as exc:
            return str(exc)
        finally:
            stream.close()
        return "closed"

    def _reconnect(self) -> socket.socket | None:
        if self._closed.wait(self.reconnect_s):
            return None
        try:
            sock = self._connect()
        except OSError:
            return None
        self._slot.revive()
        return sock


class OpenCVCameraSource(_ReaderSource):
    """A real camera through ``cv2.VideoCapture``: a device index, a video file or a URL.

    Frames are stamped in milliseconds of a monotonic clock since ``open()``; this clock is not
    the vehicle's, so use ``latest()`` (``frame_at`` compares against the source's own clock).
    A video file plays at its own frame rate and the source is dead at its end.
    """

    vehicle_time_stamps = False  # stamped by the capture's clock, not the vehicle's

    def __init__(self, spec: int | str, open_timeout_s: float = 3.0) -> None:
        self.spec = spec
        self.open_timeout_s = open_timeout_s
        self._is_file = isinstance(spec, str) and os.path.isfile(spec)
        super().__init__(str(spec))
        self._cap: cv2.VideoCapture | None = None
        self._t0 = 0.0
        self._count = 0
        self._release_lock = threading.Lock()

    def open(self) -> None:
        timeout_ms = int(self.open_timeout_s * 1000)
        params = [cv2.CAP_PROP_OPEN_TIMEOUT_MSEC, timeout_ms, cv2.CAP_PROP_READ_TIMEOUT_MSEC, timeout_ms]
        cap = cv2.VideoCapture(self.spec, cv2.CAP_ANY, params)
        if not cap.isOpened():
            raise CameraError(f"cannot open camera {self.spec!r}: check the device index, file path or URL")
        self._cap, self._t0 = cap, time.monotonic()
        first = self._grab()
        if first is None:
            cap.release()
            raise CameraError(f"camera {self.spec!r} opened but gave no frame; is it in use or empty?")
        self._slot.put(first)
        self._start_reader("opencv-reader", self._run)

    def close(self) -> None:
        """Stop reading and release the capture, never under a read that is still running (a
        network read can block up to the read timeout): a late reader releases it itself."""
        self._closed.set()
        if self._thread is not None:
            self._thread.join(self.open_timeout_s + 1.0)
            if self._thread.is_alive():
                return  # _run releases the capture when its read returns
        self._release()

    def _release(self) -> None:
        with self._release_lock:
            if self._cap is not None:
                self._cap.release()
                self._cap = None

    def _grab(self) -> Frame | None:
        assert self._cap is not None
        ok, image = self._cap.read()
        if not ok or image is None:
            return None
        if image.ndim == 2:
            image = cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
        elif image.shape[2] == 4:
            image = cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
        stamp_ms = int((time.monotonic() - self._t0) * 1000)
        frame = Frame(self._count, stamp_ms, np.ascontiguousarray(image, dtype=np.uint8))
        self._count += 1
        return frame

    def _run(self) -> None:
        assert self._cap is not None
        fps = self._cap.get(cv2.CAP_PROP_FPS) if self._is_file else 0.0
        period_s = 1.0 / fps if fps and fps > 0 else 0.0
        try:
            while not self._closed.wait(period_s):
                frame = self._grab()
                if frame is None:
                    self._slot.mark_dead("capture returned no frame (device unplugged or end of file)")
                    return
                self._slot.put(frame)
        finally:
            if self._closed.is_set():
                self._release()


def parse_colf_uri(uri: str) -> tuple[str, int]:
    """``colf://host:port`` -> (host, port)."""
    if not uri.startswith(SITL_SCHEME):
        raise CameraError(f"{uri!r} is not a camera stream URI; expected colf://host:port")
    host, sep, port = uri[len(SITL_SCHEME):].rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise CameraError(f"{uri!r} is not a camera stream URI; expected colf://host:port")
    return host, int(port)


def open_camera(spec: str, *, auto_uri: str | None = None, open_timeout_s: float = 3.0) -> CameraSource:
    """An opened source for ``spec`` ([companion.perception] camera).

    ``"auto"`` uses ``auto_uri``, the stream the vehicle's MAVLink camera advertises
    (VIDEO_STREAM_INFORMATION); ``colf://host:port`` is a SITL stream; digits are a device index;
    anything else is a video file or a URL OpenCV understands.
    """
    spec = spec.strip()
    if spec == "auto":
        if not auto_uri:
            raise CameraError(
                "camera = \"auto\" but the vehicle advertised no video stream; set [companion.perception] "
                "camera (or --camera) to colf://host:port, a device index, a file or a URL, or to \"none\" "
                "to fly a test with the pad reported as not visible"
            )
        spec = auto_uri
    source: CameraSource
    if spec.startswith(SITL_SCHEME):
        source = SitlCameraSource(spec, connect_timeout_s=open_timeout_s)
    elif spec.isdigit():
        source = OpenCVCameraSource(int(spec), open_timeout_s)
    elif "://" in spec or os.path.isfile(spec):
        source = OpenCVCameraSource(spec, open_timeout_s)
    else:
        raise CameraError(f"camera {spec!r} is neither colf://host:port, a device index, an existing file nor a URL")
    source.open()
    return source
