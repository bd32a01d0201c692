"""Shared fixtures: a seeded rng, one torch thread, free loopback ports."""

from __future__ import annotations

import contextlib
import os
import random
import re
import signal
import socket
import time
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path

import numpy as np
import pytest

from companion.testing.autopilots import udp_port_free
from companion.testing.fake_vehicle import FakeVehicle
from tests.mav_client import MavTestClient

os.environ.setdefault("OMP_NUM_THREADS", "1")


def _take_ctrl_c_back() -> None:
    """A suite started in the background of a non-interactive shell (``make test &``) inherits
    SIGINT ignored, and so does every process it starts: the tests that press Ctrl-C on a grid
    or an evaluation would then test nothing but the ignore. Python's own handler again, here
    and (exec resets a handled signal) in every child."""
    if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
        signal.signal(signal.SIGINT, signal.default_int_handler)


_take_ctrl_c_back()


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)


def free_port(kind: int = socket.SOCK_DGRAM) -> int:
    """A port on 127.0.0.1 that is free right now (for UDP or TCP)."""
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def free_rtp_port() -> int:
    """An even UDP port on 127.0.0.1 whose next port is free too: an RTP receiver (FFmpeg's SDP
    reader) binds both, RTP on the even one and RTCP on the next, and fails with "invalid data"
    when either is taken. It is drawn below the kernel's ephemeral range, so that no socket bound
    to port 0 meanwhile (the SITL's own sender among them) can take either."""
    low = 32768
    with contextlib.suppress(OSError, ValueError):
        low = int(Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()[0])
    rng = random.Random()
    for _ in range(200):
        port = rng.randrange(max(1024, low - 12000), low - 1) & ~1
        if udp_port_free(port) and udp_port_free(port + 1):
            return port
    raise RuntimeError("no free pair of UDP ports below the ephemeral range")


def gap_steps(notes: Iterable[str]) -> int:
    """The steps an episode record's notes say were not recorded for a gap: held on stale
    telemetry or flown without a camera frame (companion/control/gaps.py), as a busy machine's
    real-time SITL may cause."""
    found = (re.match(r"(\d+) steps (held on stale telemetry|flown without a camera frame)", n) for n in notes)
    return sum(int(m.group(1)) for m in found if m)


def wait_until(test: Callable[[], bool], timeout_s: float = 30.0) -> bool:
    """Poll ``test`` until it holds (True) or ``timeout_s`` passes (its last answer).

    The deadline is only an upper bound for an event that must come (a thread's write, a
    client's connect): generous, so that a starved thread at load ~10 is not a failure."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if test():
            return True
        time.sleep(0.01)
    return bool(test())


@pytest.fixture
def fake() -> Iterator[FakeVehicle]:
    """The fake PX4-like MAVLink endpoint on a free loopback port."""
    with FakeVehicle(heartbeat_period_s=0.2) as vehicle:
        yield vehicle


@pytest.fixture
def client() -> Iterator[MavTestClient]:
    """A raw pymavlink test client on a free loopback UDP port (the SITL sends there)."""
    c = MavTestClient()
    yield c
    c.close()


@pytest.fixture(autouse=True, scope="session")
def _torch_single_thread() -> None:
    try:
        import torch
    except ImportError:  # pragma: no cover - torch is a core dependency
        return
    torch.set_num_threads(1)


REALTIME_NICE = -10
STARTING_NICE = os.getpriority(os.PRIO_PROCESS, 0)  # what the shell gave pytest
"""Niceness of a test that flies in real time (and of every process it starts). A real-time
SITL, PX4 SIH, ArduCopter or the console fall behind their wall clock when a loaded machine
(load ~10 on 2 cores) shares the CPU evenly; a flight stack is given priority on a real
companion computer too. Lockstep and unit tests keep the default priority."""


@contextlib.contextmanager
def _niceness(nice: int) -> Iterator[None]:
    """This process (and what it starts meanwhile) at ``nice``, if it may; back afterwards."""
    before = os.getpriority(os.PRIO_PROCESS, 0)
    try:
        os.setpriority(os.PRIO_PROCESS, 0, nice)
    except PermissionError:  # not root: the default priority, as before
        pass
    try:
        yield
    finally:
        with contextlib.suppress(PermissionError):
            os.setpriority(os.PRIO_PROCESS, 0, before)


def _realtime_if_marked(request: pytest.FixtureRequest) -> contextlib.AbstractContextManager[None]:
    marked = request.node.get_closest_marker("realtime") is not None
    return _niceness(REALTIME_NICE) if marked else contextlib.nullcontext()


@pytest.fixture(autouse=True, scope="module")
def _realtime_module(request: pytest.FixtureRequest) -> Iterator[None]:
    """Modules marked ``realtime`` (their module-scoped vehicles start inside this)."""
    with _realtime_if_marked(request):
        yield


@pytest.fixture(autouse=True)
def _realtime_test(request: pytest.FixtureRequest) -> Iterator[None]:
    """Single tests marked ``realtime``."""
    with _realtime_if_marked(request):
        yield


ONE_AFTER_ANOTHER = "one-after-another"
"""The xdist group of the heaviest wall-clock tests, run in turn on one worker: the real autopilots
(PX4 SIH at 4x, ArduCopter at 5x), then the browser tests (chromium and the console), then the
Ray backend's (a local instance has a fixed 30 s for its raylet). Side by side at the start of the
suite, at the real-time priority, they drove the load to 12-19 on 2 cores: Ray missed its start
(load 18, bench/results/ci-fresh-2026-12-07-36-failed.txt) and the companion fell behind PX4 SIH
at 4x (load 12, -37-failed.txt). In turn the CI's peak was 8.7 (-38.txt), the suite no slower."""


def grouped_first(items: list[pytest.Item]) -> list[pytest.Item]:
    """The tests of an xdist group (the long real-time and CPU-bound units) before the others,
    each set in collection order. ``--dist loadgroup`` hands work out in collection order; a long
    group collected late (tests/numeric) started when the short tests were nearly done and made
    the suite wait for it alone."""
    return sorted(items, key=lambda item: item.get_closest_marker("xdist_group") is None)


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    items[:] = grouped_first(items)
