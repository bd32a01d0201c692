"""MAVLink fuzzing over loopback UDP: seeded hostile packets for a running SITL or a
companion link, with a probe between batches that tells a hang from a slow answer.

Packets (one datagram each): random bytes; valid messages truncated or with one bit flipped
(the CRC must catch them); valid messages whose float fields are NaN, infinite or huge and
whose integers are at their limits; and valid messages with shuffled sequence numbers. The
templates are what a vehicle or a companion acts on (commands, setpoints, MANUAL_CONTROL,
PARAM_SET, telemetry). Intact messages that would legitimately arm, take off or move a
vehicle are never sent whole, so after a run the vehicle must still be disarmed on the ground:
anything else means it obeyed something that was not a valid request.
"""

from __future__ import annotations

import math
import socket
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

import numpy as np
from pymavlink.dialects.v20 import common as M

EXTREME_FLOATS = (math.nan, math.inf, -math.inf, 3.4e38, -3.4e38, 1e-45, 0.0, -0.0, 1e9, -1e9)
KINDS = ("random", "truncated", "bitflip", "extreme", "reordered")
HANG_PROBES = 12  # a target silent for this many probe timeouts in a row has hung
CommandList = list[tuple[int, ...]]

# commands whose intact form would legitimately change what the vehicle does: only corrupted
PROTECTED_COMMANDS = (M.MAV_CMD_COMPONENT_ARM_DISARM, M.MAV_CMD_NAV_TAKEOFF)
# commands that may arrive intact with extreme parameters: the vehicle must refuse or ignore them
PROBED_COMMANDS = (M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAV_CMD_REQUEST_MESSAGE, M.MAV_CMD_DO_SET_MODE,
                   M.MAV_CMD_NAV_LAND, M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, 0, 65535)


@dataclass
class FuzzReport:
    """What a fuzz run did and what went wrong (zero crashes and hangs is a pass)."""

    packets: int = 0
    by_kind: dict[str, int] = field(default_factory=lambda: dict.fromkeys(KINDS, 0))
    probes: int = 0
    slow: int = 0  # probes answered only after their first timeout (a loaded machine)
    hangs: int = 0  # probes still unanswered after HANG_PROBES timeouts: the target stopped
    crashes: int = 0  # the target died or reported an internal error
    notes: list[str] = field(default_factory=list)


def _f(rng: np.random.Generator) -> float:
    """A float field: extreme half of the time, else an ordinary value."""
    if rng.random() < 0.5:
        return float(EXTREME_FLOATS[int(rng.integers(len(EXTREME_FLOATS)))])
    return float(rng.normal(0.0, 10.0))


def _u(rng: np.random.Generator, bits: int) -> int:
    return int(rng.choice([0, 1, (1 << bits) - 1, 1 << (bits - 1), int(rng.integers(1 << bits))]))


def _protected_template(rng: np.random.Generator) -> M.MAVLink_message:
    cmd = int(rng.choice(PROTECTED_COMMANDS))
    return M.MAVLink_command_long_message(1, 1, cmd, 0, 1.0, 0, 0, 0, 0, 0, 0)


def _valid_extreme(rng: np.random.Generator) -> M.MAVLink_message:
    """An intact message with extreme fields that must not make a grounded vehicle fly."""
    which = int(rng.integers(7))
    f = [_f(rng) for _ in range(16)]
    if which == 0:
        return M.MAVLink_set_position_target_local_ned_message(
            _u(rng, 32), 1, 1, _u(rng, 8), _u(rng, 16), *f[:11])
    if which == 1:
        return M.MAVLink_manual_control_message(1, *(int(rng.integers(-32768, 32768)) for _ in range(4)), _u(rng, 16))
    if which == 2:
        cmd = int(rng.choice(PROBED_COMMANDS))
        return M.MAVLink_command_long_message(_u(rng, 8), _u(rng, 8), cmd, _u(rng, 8), *f[:7])
    if which == 3:
        name = bytes(rng.choice([b"MIS_TAKEOFF_ALT", b"COM_OF_LOSS_T", b"MPC_XY_VEL_MAX", bytes(rng.integers(1, 256, 16, dtype=np.uint8))]))
        return M.MAVLink_param_set_message(1, 1, name[:16], f[0], _u(rng, 8))
    if which == 4:
        return M.MAVLink_set_mode_message(1, _u(rng, 8), _u(rng, 32))
    if which == 5:
        return M.MAVLink_attitude_message(_u(rng, 32), *f[:6])
    return M.MAVLink_local_position_ned_message(_u(rng, 32), *f[:6])


def _template(rng: np.random.Generator) -> M.MAVLink_message:
    return _protected_template(rng) if rng.random() < 0.5 else _valid_extreme(rng)


def packets(rng: np.random.Generator, count: int, system_id: int = 245, component_id: int = 191) -> Iterator[tuple[str, bytes]]:
    """``count`` (kind, datagram) pairs, reproducible for the generator's seed."""
    mav = M.MAVLink(None, system_id, component_id)
    for _ in range(count):
        kind = KINDS[int(rng.integers(len(KINDS)))]
        if kind == "random":
            n = int(rng.integers(1, 300))
            data = rng.integers(0, 256, n, dtype=np.uint8).tobytes()
            if rng.random() < 0.5:  # start like a MAVLink 2 packet, so the parser goes deeper
                data = bytes([0xFD]) + data[1:]
            yield kind, data
            continue
        packed = bytes(_template(rng).pack(mav)) if kind != "extreme" else bytes(_valid_extreme(rng).pack(mav))
        if kind == "truncated":
            packed = packed[: int(rng.integers(1, len(packed)))]
        elif kind == "bitflip":
            buf = bytearray(packed)
            bit = int(rng.integers(len(buf) * 8))
            buf[bit // 8] ^= 1 << (bit % 8)
            packed = bytes(buf)
        elif kind == "reordered":
            mav.seq = int(rng.integers(256))
            packed = bytes(_valid_extreme(rng).pack(mav))
        yield kind, packed


Probe = Callable[[], bool]


def fuzz_udp(
    address: tuple[str, int], count: int, seed: int, probe: Probe, alive: Callable[[], bool],
    batch: int = 100, sock: socket.socket | None = None, system_id: int = 245,
) -> FuzzReport:
    """Send ``count`` fuzz datagrams to ``address`` in batches; after each batch ``probe()`` must
    answer (False = a hang) and ``alive()`` must hold (False = a crash; the run stops)."""
    rng = np.random.default_rng(seed)
    own = sock is None
    s = sock or socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    report = FuzzReport()
    try:
        sent_in_batch = 0
        for kind, data in packets(rng, count, system_id):
            s.sendto(data, address)
            report.packets += 1
            report.by_kind[kind] += 1
            sent_in_batch += 1
            if sent_in_batch >= batch:
                sent_in_batch = 0
                if not _check(report, probe, alive):
                    break
        else:
            _check(report, probe, alive)
    finally:
        if own:
            s.close()
    return report


def _check(report: FuzzReport, probe: Probe, alive: Callable[[], bool]) -> bool:
    report.probes += 1
    if not probe():
        if any(probe() for _ in range(HANG_PROBES - 1)):
            report.slow += 1
        else:
            report.hangs += 1
            report.notes.append(f"probe {report.probes} unanswered after {report.packets} packets")
    if not alive():
        report.crashes += 1
        report.notes.append(f"target gone after {report.packets} packets")
        return False
    return True


def retrying(send: Callable[[], None], answered: Callable[[], bool], timeout_s: float, every_s: float = 0.25) -> bool:
    """Send a probe every ``every_s`` until it is answered or ``timeout_s`` passes: a datagram
    lost in a full socket buffer is not a hang, a target silent for ``timeout_s`` is."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        send()
        if wait_for(answered, min(every_s, max(0.0, deadline - time.monotonic()))):
            return True
    return False


def wait_for(test: Callable[[], bool], timeout_s: float) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if test():
            return True
        time.sleep(0.002)
    return test()
