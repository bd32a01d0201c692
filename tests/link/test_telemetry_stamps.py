"""Both links keep the vehicle's own stamp of each telemetry message, the freshness rule's input."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from companion.config import LinkConfig
from companion.link import open_link
from companion.link.base import VehicleLink
from companion.testing import FakeVehicle
from tests.conftest import wait_until


@pytest.fixture
def quiet_fake() -> Iterator[FakeVehicle]:
    """A fake that sends only what the test sends (and heartbeats)."""
    with FakeVehicle(heartbeat_period_s=0.2, stream_rate_hz=0.0) as vehicle:
        yield vehicle


def _open(fake: FakeVehicle, kind: str) -> VehicleLink:
    if kind == "mavsdk":
        pytest.importorskip("mavsdk")
    cfg = LinkConfig(connection=fake.connection_string, request_rates_on_connect=False)
    link = open_link(cfg, kind=kind)
    link.connect(timeout_s=10.0)
    return link


def _stamps(link: VehicleLink) -> tuple[int | None, int | None]:
    snap = link.state()
    assert snap is not None
    return snap.position_time_boot_ms, snap.attitude_time_boot_ms


@pytest.mark.parametrize("kind", ["pymavlink", "mavsdk"])
def test_each_message_keeps_its_own_stamp_not_the_newest_of_any(quiet_fake: FakeVehicle, kind: str) -> None:
    enc = quiet_fake.encoder
    link = _open(quiet_fake, kind)
    try:
        assert _stamps(link) == (None, None)  # nothing sent yet: no stamp, not a guess
        quiet_fake.send_message(enc.local_position_ned_encode(1000, 1.0, 2.0, -3.0, 0.1, 0.2, 0.3))
        quiet_fake.send_message(enc.attitude_encode(900, 0.01, 0.02, 0.03, 0.0, 0.0, 0.0))
        assert wait_until(lambda: _stamps(link) == (1000, 900), 10.0), _stamps(link)
        snap = link.state()
        assert snap is not None and snap.position_ned_m == pytest.approx((1.0, 2.0, -3.0))
        # a newer message of another kind (the frame marker) says nothing of position or attitude
        quiet_fake.send_message(enc.system_time_encode(0, 5000))
        quiet_fake.send_message(enc.attitude_encode(1100, 0.01, 0.02, 0.03, 0.0, 0.0, 0.0))
        assert wait_until(lambda: _stamps(link) == (1000, 1100), 10.0), _stamps(link)
        # a message carried late, with an old stamp, keeps its old stamp (it is old news)
        quiet_fake.send_message(enc.local_position_ned_encode(950, 5.0, 5.0, -5.0, 0.0, 0.0, 0.0))
        assert wait_until(lambda: _stamps(link) == (950, 1100), 10.0), _stamps(link)
    finally:
        link.close()
