"""A MAVLink telemetry log as MAVProxy and QGroundControl write it (``.tlog``).

Each record is the 8-byte big-endian time of arrival or sending in microseconds since the
Unix epoch, followed by the raw MAVLink packet; both directions go into one file, so
``pymavlink.mavutil.mavlink_connection(path)`` and MAVExplorer replay it. As MAVProxy does, the
two lowest bits of the time carry the direction: 0 for received (link 0), 3 for sent.
"""

from __future__ import annotations

import struct
import threading
import time
from pathlib import Path

RECEIVED_LINK = 0  # MAVProxy: link number of the vehicle link
SENT_LINK = 3  # MAVProxy: messages it sent


class TlogWriter:
    """Appends packets to a .tlog; safe to call from the link's threads concurrently."""

    def __init__(self, path: str | Path, flush_every: int = 50) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._file = self.path.open("ab")
        self._lock = threading.Lock()
        self._flush_every = max(1, flush_every)
        self._unflushed = 0
        self.records = 0

    def write(self, packet: bytes, sent: bool = False, wall_time_s: float | None = None) -> None:
        """Log one packet (no-op once closed); ``sent`` marks our own packets."""
        usec = int((time.time() if wall_time_s is None else wall_time_s) * 1e6)
        usec = (usec & ~3) | (SENT_LINK if sent else RECEIVED_LINK)
        with self._lock:
            if self._file.closed:
                return
            self._file.write(struct.pack(">Q", usec) + bytes(packet))
            self.records += 1
            self._unflushed += 1
            if self._unflushed >= self._flush_every:
                self._file.flush()
                self._unflushed = 0

    def flush(self) -> None:
        with self._lock:
            if not self._file.closed:
                self._file.flush()
                self._unflushed = 0

    def close(self) -> None:
        with self._lock:
            self._file.close()
