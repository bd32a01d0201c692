"""Shared fixtures: a seeded rng, one torch thread, free loopback ports."""

from __future__ import annotations

import os
import socket
import time
from collections.abc import Callable, Iterator

import numpy as np
import pytest

from companion.testing.fake_vehicle import FakeVehicle
from tests.mav_client import MavTestClient

os.environ.setdefault("OMP_NUM_THREADS", "1")


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)


def free_port(kind: int = socket.SOCK_DGRAM) -> int:
    """A port on 127.0.0.1 that is free right now (for UDP or TCP)."""
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


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
