"""The setpoint-gap script (``python -m companion.testing.setpoint_gap``) against our SITL as PX4
over real loopback sockets: a gap in the setpoints longer than COM_OF_LOSS_T leaves OFFBOARD,
the vehicle says so, and the stream's return gives OFFBOARD back (real PX4 SIH did the same:
results/conformance/setpoint-gap.json). What the vehicle says is collected by the scripts'
shared STATUSTEXT reading, the one the precision-landing conformance uses too."""

from __future__ import annotations

from pathlib import Path

import pytest

from companion.simulator import start_sitl
from companion.testing.autopilots import free_udp_port
from companion.testing.setpoint_gap import fly_gap

pytestmark = [pytest.mark.realtime, pytest.mark.e2e]
SPEED = 2.0  # COM_OF_LOSS_T is then 2 s of the vehicle's time: 1 s of the wall's, as PX4's rcS sets it


def test_a_gap_longer_than_the_loss_time_fails_safe_says_so_and_returns_to_offboard(tmp_path: Path) -> None:
    config = tmp_path / "sitl.toml"
    config.write_text("[sitl.personality]\nprearm_settle_s = 1.0\n")
    port = free_udp_port()
    sitl = start_sitl(port, clock="realtime", config=config, camera=False, timeout_s=120.0,
                      extra_args=["--autopilot", "px4", "--speed", f"{SPEED:g}"])
    try:
        out = fly_gap(f"udpin:127.0.0.1:{port}", gap_s=5.0)
    finally:
        sitl.stop()
    assert out.errors == []
    assert out.loss_t_s == pytest.approx(SPEED)
    assert out.offboard_ack == "ACCEPTED"
    assert out.left_offboard and out.back_in_offboard, out.modes
    said = [text for _, text in out.texts]
    lost = next(i for i, text in enumerate(said) if text.startswith("Offboard setpoints lost"))
    assert any(text == "Offboard setpoints regained" for text in said[lost + 1:]), said
