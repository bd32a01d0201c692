"""The session's port to one vehicle (companion/control/link_port.py): its dialect and its hold."""

from __future__ import annotations

import logging

import pytest

from companion.control.link_port import HOLD, LinkPort
from companion.errors import CommandRejected, LinkError
from companion.link.dialect import ARDUPILOT, PX4
from companion.link.home import HomeFrame
from companion.msg.setpoint import VelocitySetpoint
from companion.msg.snapshot import VehicleSnapshot


class Link:
    def __init__(self, autopilot: str | None = "ARDUPILOTMEGA", refuse: bool = False) -> None:
        self.autopilot, self.refuse = autopilot, refuse
        self.calls: list[tuple[str, object]] = []

    def state(self) -> VehicleSnapshot | None:
        if self.autopilot is None:
            return None
        return VehicleSnapshot(0.0, 1000, 1000, 1, self.autopilot, True, "GUIDED", "IN_AIR", (0.0, 0.0, -3.0),
                               (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0.0, True, True)

    def send_velocity_body(self, sp: VelocitySetpoint, echo_time_boot_ms: int | None = None) -> None:
        self.calls.append(("setpoint", (sp, echo_time_boot_ms)))

    def set_mode(self, name: str) -> None:
        self.calls.append(("mode", name))
        if self.refuse:
            raise CommandRejected(f"mode {name}", "DENIED", "the vehicle said no")


def port(link: Link, **kwargs: object) -> LinkPort:
    return LinkPort(link, True, 10.0, HomeFrame(), **kwargs)  # type: ignore[arg-type]


def test_the_dialect_is_the_given_one_else_the_heartbeats() -> None:
    assert port(Link("ARDUPILOTMEGA")).dialect is ARDUPILOT
    assert port(Link("ARDUPILOTMEGA"), dialect=PX4).dialect is PX4
    silent = Link(None)
    waiting = port(silent)
    with pytest.raises(LinkError, match="no HEARTBEAT"):
        waiting.dialect  # noqa: B018
    silent.autopilot = "PX4"
    assert waiting.dialect is PX4
    silent.autopilot = "ARDUPILOTMEGA"
    assert waiting.dialect is PX4  # told once, kept


def test_holding_answers_the_frame_then_asks_for_the_mode_and_a_refusal_is_said(
        caplog: pytest.LogCaptureFixture) -> None:
    link = Link()
    p = port(link)
    p.frame_ms = 1200
    p.hold_in("LOITER")
    assert link.calls == [("setpoint", (HOLD, 1200)), ("mode", "LOITER")]
    refusing = Link(refuse=True)
    with caplog.at_level(logging.ERROR):
        port(refusing).hold_in("LOITER")
    assert [name for name, _ in refusing.calls] == ["setpoint", "mode"]
    assert "could not switch to hold" in caplog.text
