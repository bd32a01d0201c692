"""A lossy, slow link: the seeded proxy's faults, then offboard loss through it: the vehicle holds
after COM_OF_LOSS_T, lands, and the companion's link resumes when the link comes back."""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Iterator

import pytest

from companion.config import LinkConfig
from companion.errors import ColError
from companion.link.mavlink_link import MavlinkLink
from companion.msg.setpoint import VelocitySetpoint
from companion.simulator import SimulatorClient, SitlProcess, start_sitl
from companion.testing.lossy_proxy import LinkFaults, LossyProxy
from tests.conftest import free_port, wait_until

pytestmark = pytest.mark.realtime  # flies in real time: a higher priority where allowed

SPEED = 2.0  # the proxied SITL's real-time speed factor
COM_OF_LOSS_T = 1.0 * SPEED  # the SITL's default x its speed, as PX4's SITL start script sets it (docs/sitl.md)


def _pair() -> tuple[socket.socket, socket.socket]:
    a, b = (socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(2))
    for s in (a, b):
        s.bind(("127.0.0.1", 0))
        s.settimeout(1.0)
    return a, b


def _receive_all(sock: socket.socket) -> list[int]:
    """Everything until the socket is quiet for its timeout."""
    got = []
    while True:
        try:
            got.append(int(sock.recv(64)))
        except TimeoutError:
            return got


@pytest.mark.parametrize("faults", [LinkFaults(), LinkFaults(loss=0.3), LinkFaults(duplicate=0.2), LinkFaults(reorder=0.2)],
                         ids=["clean", "loss", "duplicate", "reorder"])
def test_the_proxy_applies_each_fault_as_seeded(faults: LinkFaults) -> None:
    vehicle, companion = _pair()
    with LossyProxy(companion.getsockname()[1], to_companion=faults, seed=1) as proxy:
        got: list[int] = []
        reader = threading.Thread(target=lambda: got.extend(_receive_all(companion)))
        reader.start()
        for i in range(1000):
            vehicle.sendto(str(i).encode(), ("127.0.0.1", proxy.vehicle_port))
            if i % 20 == 0:
                time.sleep(0.002)
        reader.join()
    st = proxy.stats["down"]
    assert st.dropped + st.forwarded - st.duplicated == 1000
    assert len(got) == st.forwarded
    assert st.dropped == pytest.approx(1000 * faults.loss, abs=60)
    assert st.duplicated == pytest.approx(1000 * faults.duplicate, abs=60)
    out_of_order = sum(b < a for a, b in zip(got, got[1:]))
    assert (out_of_order > 50) == (faults.reorder > 0)
    vehicle.close()
    companion.close()


def test_the_proxy_delays_and_blacks_out() -> None:
    vehicle, companion = _pair()
    with LossyProxy(companion.getsockname()[1], to_companion=LinkFaults(delay_s=0.2)) as proxy:
        t0 = time.monotonic()
        vehicle.sendto(b"1", ("127.0.0.1", proxy.vehicle_port))
        assert companion.recv(64) == b"1" and time.monotonic() - t0 >= 0.2
        proxy.cut()
        vehicle.sendto(b"2", ("127.0.0.1", proxy.vehicle_port))
        assert _receive_all(companion) == [] and proxy.stats["down"].blacked_out == 1
    vehicle.close()
    companion.close()


@pytest.fixture
def proxied() -> Iterator[tuple[SitlProcess, LossyProxy, MavlinkLink, SimulatorClient]]:
    port = free_port()
    proxy = LossyProxy(port, seed=3).start()
    sitl = start_sitl(proxy.vehicle_port, clock="realtime", camera=False, extra_args=["--speed", f"{SPEED:g}"])
    link = MavlinkLink(LinkConfig(connection=f"udpin:127.0.0.1:{port}"))
    sim = SimulatorClient("127.0.0.1", sitl.control_port)
    try:
        link.connect(timeout_s=20.0)
        yield sitl, proxy, link, sim
    finally:
        link.close()
        sim.close()
        sitl.stop()
        proxy.close()


class SetpointStream:
    """Streams a gentle setpoint at 20 Hz (wall) from a thread, as a companion does; a lost link
    raises in send, which is counted and retried."""

    def __init__(self, link: MavlinkLink) -> None:
        self.link, self.refused = link, 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                self.link.send_velocity_body(VelocitySetpoint(0.2, 0.0, 0.0, 0.0))
            except ColError:
                self.refused += 1
            self._stop.wait(0.05)

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(2.0)


@pytest.mark.e2e
def test_offboard_loss_through_the_proxy_holds_lands_and_the_link_resumes(proxied) -> None:
    _, proxy, link, sim = proxied
    link.arm()
    link.takeoff(2.5)
    assert wait_until(lambda: sim.truth()["vehicle_ned"][2] < -2.0, 30.0)
    stream = SetpointStream(link)
    try:
        time.sleep(0.5)
        link.set_mode("OFFBOARD")
        assert wait_until(lambda: sim.truth()["mode"] == "OFFBOARD", 5.0)
        proxy.cut()  # the radio goes silent both ways
        assert wait_until(lambda: sim.truth()["mode"] == "AUTO.LOITER", 10.0)
        t = sim.truth()
        assert t["failsafe_since_s"] - t["last_setpoint_s"] <= COM_OF_LOSS_T + 0.1
        assert wait_until(lambda: not link.link_alive(), 5.0)  # the companion noticed
        assert wait_until(lambda: sim.truth()["mode"] == "AUTO.LAND", 15.0)
        assert wait_until(lambda: sim.truth()["landed"], 30.0)
        proxy.cut(False)
        assert wait_until(link.link_alive, 10.0)  # and it resumes by itself
        assert link.stats().reconnections >= 1 and stream.refused > 0
    finally:
        stream.stop()
    assert wait_until(lambda: not sim.truth()["armed"], 20.0)
    link.arm()  # commands work again over the restored link: ACCEPTED, and the heartbeat says so
    assert wait_until(lambda: (s := link.state()) is not None and s.armed, 15.0)
