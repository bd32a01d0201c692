"""The pymavlink link's I/O half: the connection, its thread, and what it learns.

One thread reads every message, folds the vehicle's telemetry into a new frozen snapshot
(swapped in one assignment), offers replies to waiters (COMMAND_ACK, PARAM_VALUE), hands
MANUAL_CONTROL to a callback, writes the tlog and sends our own HEARTBEAT. Other threads only
call :meth:`MavlinkIO.send`, under a lock; they never touch the parser.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

from companion.config import LinkConfig
from companion.errors import LinkLost
from companion.link.base import LinkStats, ManualControlCallback
from companion.link.connection import ConnectionSpec, open_mavlink
from companion.link.manual_control import (
    addressed_to_us,
    deliver_manual_control,
    parse_manual_control,
)
from companion.link.signing import diagnose, enable_signing, load_key
from companion.link.telemetry import (
    InvalidTelemetry,
    apply_message,
    initial_snapshot,
    is_vehicle_heartbeat,
)
from companion.link.tlog import TlogWriter
from companion.link.waiters import Waiters, wait_until
from companion.msg.snapshot import VehicleSnapshot

log = logging.getLogger(__name__)

SnapshotTest = Callable[[VehicleSnapshot | None], bool]


class MavlinkIO:
    """Connection + I/O thread + the newest snapshot of the vehicle it adopted."""

    def __init__(
        self,
        cfg: LinkConfig,
        spec: ConnectionSpec,
        tlog_path: str | Path | None,
        clock: Callable[[], float],
    ) -> None:
        self.cfg = cfg
        self._spec = spec
        self._key = load_key(cfg)  # a bad key file fails here, before any port is opened
        self._clock = clock
        self._tlog = TlogWriter(tlog_path) if tlog_path is not None else None
        self.waiters = Waiters()
        self.counts: Counter[str] = Counter()
        self.snapshot: VehicleSnapshot | None = None
        self.target: tuple[int, int] | None = None  # vehicle's (system, component)
        self.vehicle_type = 0
        self.manual_callback: ManualControlCallback | None = None
        self._conn: Any = None
        self._last_heard_s: float | None = None
        self._was_alive = False
        self._changed = threading.Condition()
        self._send_lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # ================================================================ lifecycle
    def start(self) -> None:
        """Open the port and start the thread (once)."""
        if self._stop.is_set():
            raise LinkLost("this link was closed; open a new one")
        if self._thread is None:
            self._conn = open_mavlink(self._spec, self.cfg.source_system, self.cfg.source_component)
            enable_signing(self._conn.mav, self._key)
            self._thread = threading.Thread(target=self._run, name="mavlink-link", daemon=True)
            self._thread.start()

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)
        with self._send_lock:
            if self._conn is not None:
                self._conn.close()
                self._conn = None
        if self._tlog is not None:
            self._tlog.close()
        with self._changed:
            self._changed.notify_all()

    @property
    def closed(self) -> bool:
        return self._stop.is_set()

    # ================================================================ state
    def alive(self) -> bool:
        heard = self._last_heard_s
        return heard is not None and self._clock() - heard < self.cfg.link_lost_s

    def stats(self) -> LinkStats:
        return LinkStats(**dict(self.counts))

    def signing_problem(self) -> str | None:
        """Why the vehicle's messages are unusable, if MAVLink signing explains it."""
        conn = self._conn
        return None if conn is None else diagnose(conn.mav, self.cfg.signing_key_file)

    def wait(
        self, ready: SnapshotTest, timeout_s: float, on_loss: Callable[[], None] | None = None
    ) -> VehicleSnapshot | None:
        """The snapshot once ``ready`` holds for it; None on timeout or close.

        ``on_loss`` is called (and may raise) when the link is lost while waiting.
        """
        def check_link() -> None:
            if on_loss is not None and not self.alive():
                on_loss()

        return wait_until(self._changed, lambda: self.snapshot, ready, timeout_s, self._clock,
                          lambda: self.closed, check_link)

    # ================================================================ sending
    @property
    def mav(self) -> Any:
        """The MAVLink 2 encoder (our system and component ids)."""
        conn = self._conn
        if conn is None:
            raise LinkLost("the link is not open; call connect() first")
        return conn.mav

    def send(self, msg: Any) -> None:
        with self._send_lock:
            conn = self._conn
            if conn is None:
                raise LinkLost("the link is closed; open a new one")
            conn.mav.send(msg)
            if self._tlog is not None:
                self._tlog.write(msg.get_msgbuf(), sent=True)

    def _send_heartbeat(self) -> None:
        try:
            self.send(
                self.mav.heartbeat_encode(
                    mavlink.MAV_TYPE_ONBOARD_CONTROLLER, mavlink.MAV_AUTOPILOT_INVALID, 0, 0,
                    mavlink.MAV_STATE_ACTIVE,
                )
            )  # fmt: skip
        except (OSError, LinkLost):
            self.counts["thread_errors"] += 1

    # ================================================================ thread
    def _run(self) -> None:
        next_heartbeat = self._clock()
        while not self._stop.is_set():
            now = self._clock()
            if now >= next_heartbeat:
                self._send_heartbeat()
                next_heartbeat = now + self.cfg.heartbeat_period_s
            self._track_liveness()
            try:
                msg = self._conn.recv_msg()
                if msg is None:
                    self._conn.select(min(0.02, max(0.0, next_heartbeat - now)))
                    continue
                self._handle(msg)
            except Exception:  # noqa: BLE001 - the I/O thread must outlive any bad input
                self.counts["thread_errors"] += 1
                log.exception("MAVLink I/O thread error (continuing)")
                time.sleep(0.01)

    def _track_liveness(self) -> None:
        alive = self.alive()
        if self._was_alive and not alive:
            self.counts["link_losses"] += 1
            log.warning("MAVLink link lost: nothing heard for %.1f s", self.cfg.link_lost_s)
            with self._changed:
                self._changed.notify_all()
        self._was_alive = alive

    def _handle(self, msg: Any) -> None:
        kind = msg.get_type()
        if kind == "BAD_DATA":
            self.counts["bad_data"] += 1
            return
        self.counts["messages_received"] += 1
        if self._tlog is not None:
            self._tlog.write(msg.get_msgbuf())
        now = self._clock()
        if kind == "MANUAL_CONTROL":
            self._manual_control(msg, now)
        elif self.target is None:
            if is_vehicle_heartbeat(msg):
                self._adopt_vehicle(msg, now)
        elif msg.get_srcSystem() == self.target[0]:
            self._heard(now)
            self.waiters.offer(msg)
            self._fold(msg, now)

    def _adopt_vehicle(self, msg: Any, now: float) -> None:
        self.target = (msg.get_srcSystem(), msg.get_srcComponent())
        self.vehicle_type = int(msg.type)
        self._heard(now)
        self._publish(initial_snapshot(msg, now))
        log.info("vehicle found: system %d component %d", *self.target)

    def _heard(self, now: float) -> None:
        if self._last_heard_s is not None and not self.alive():
            self.counts["reconnections"] += 1
            log.warning("MAVLink link back after loss")
        self._last_heard_s = now
        self._was_alive = True

    def _fold(self, msg: Any, now: float) -> None:
        snapshot = self.snapshot
        if snapshot is None:
            return
        try:
            new = apply_message(snapshot, msg, now, self.cfg.frame_marker)
        except InvalidTelemetry:
            self.counts["telemetry_rejected"] += 1
            return
        self._publish(new)

    def _publish(self, snapshot: VehicleSnapshot) -> None:
        with self._changed:
            self.snapshot = snapshot
            self._changed.notify_all()

    def _manual_control(self, msg: Any, now: float) -> None:
        self.counts["manual_control_received"] += 1
        vehicle = self.target[0] if self.target is not None else None
        if addressed_to_us(msg.target, self.cfg.source_system, vehicle):
            value = parse_manual_control(msg, now)
            deliver_manual_control(value, msg.get_srcSystem(), self.counts, self.manual_callback)
