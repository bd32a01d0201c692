"""A small, independent pymavlink client for testing the SITL over real UDP sockets.

Deliberately not the companion's link: the SITL's tests must not depend on the code it serves.
"""

from __future__ import annotations

import math
import socket
import time
from collections import deque
from collections.abc import Callable

from pymavlink.dialects.v20 import common as M

BODY_NED = 8
LOCAL_NED = 1
VEL_YAWRATE = 0x5C7


class MavTestClient:
    """Listens on a loopback UDP port (the SITL sends there) and answers the first sender."""

    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.2)
        self.port = self.sock.getsockname()[1]
        self.peer: tuple[str, int] | None = None
        self.mav = M.MAVLink(None, 255, 190)
        self.parser = M.MAVLink(None, 0, 0)
        self.parser.robust_parsing = True
        self.latest: dict[str, M.MAVLink_message] = {}
        self.seen: list[M.MAVLink_message] = []
        self.statustexts: list[str] = []
        self.inbox: deque[M.MAVLink_message] = deque(maxlen=5000)

    def close(self) -> None:
        self.sock.close()

    def pump(self, timeout_s: float = 0.2) -> list[M.MAVLink_message]:
        """Read what has arrived (waiting up to ``timeout_s`` for the first datagram)."""
        out: list[M.MAVLink_message] = []
        self.sock.settimeout(timeout_s)
        while True:
            try:
                data, addr = self.sock.recvfrom(65535)
            except (TimeoutError, BlockingIOError):
                return out
            self.peer = addr
            for msg in self.parser.parse_buffer(data) or []:
                if msg.get_type() == "BAD_DATA":
                    continue
                self.latest[msg.get_type()] = msg
                if msg.get_type() == "STATUSTEXT":
                    self.statustexts.append(msg.text)
                out.append(msg)
                self.inbox.append(msg)
            self.sock.settimeout(0.0)

    def wait_for(self, predicate: Callable[[M.MAVLink_message], bool], timeout_s: float = 10.0) -> M.MAVLink_message:
        """The first message (received since the last match) that satisfies ``predicate``."""
        deadline = time.monotonic() + timeout_s
        while True:
            while self.inbox:
                msg = self.inbox.popleft()
                if predicate(msg):
                    return msg
            if time.monotonic() > deadline:
                break
            self.pump(0.1)
        raise TimeoutError("expected message did not arrive")

    def send(self, msg: M.MAVLink_message) -> None:
        assert self.peer is not None, "no telemetry received yet: unknown peer"
        self.sock.sendto(msg.pack(self.mav), self.peer)

    def send_raw(self, data: bytes) -> None:
        assert self.peer is not None
        self.sock.sendto(data, self.peer)

    def command(self, cmd: int, *params: float, target_component: int = 1, timeout_s: float = 5.0) -> int:
        """COMMAND_LONG and its ACK's result."""
        p = list(params) + [0.0] * (7 - len(params))
        self.send(M.MAVLink_command_long_message(1, target_component, cmd, 0, *p))
        ack = self.wait_for(lambda m: m.get_type() == "COMMAND_ACK" and m.command == cmd, timeout_s)
        return int(ack.result)

    def body_velocity(self, forward: float, right: float = 0.0, down: float = 0.0, yaw_rate: float = 0.0, echo_ms: int = 0) -> None:
        self.send(M.MAVLink_set_position_target_local_ned_message(
            echo_ms, 1, 1, BODY_NED, VEL_YAWRATE, 0, 0, 0, forward, right, down, 0, 0, 0, 0, yaw_rate))

    def mode_custom(self) -> int:
        hb = self.latest.get("HEARTBEAT")
        return -1 if hb is None else int(hb.custom_mode)

    def armed(self) -> bool:
        hb = self.latest.get("HEARTBEAT")
        return bool(hb and hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED)


def nan7() -> list[float]:
    return [math.nan] * 7
