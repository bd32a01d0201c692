"""The conformance scripts' opening against silence: they say why they stopped and leave nothing open."""

from __future__ import annotations

from companion.testing.conformance import PrecLandScript, Script
from companion.testing.setpoint_gap import GapScript
from tests.conftest import free_port


def silent_script(kind: type[Script]) -> Script:
    """A script whose vehicle and second link are loopback ports nobody sends to."""
    script = kind(f"udpin:127.0.0.1:{free_port()}", texts_from=f"udpin:127.0.0.1:{free_port()}")
    script.hello_timeout_s = 0.3
    return script


def closed(script: Script) -> bool:
    assert script.listener is not None
    return script.mav.port.fileno() == -1 and not script.listener._thread.is_alive()


def test_no_heartbeat_is_reported_and_both_links_are_closed() -> None:
    script = silent_script(Script)
    out = script.run()
    assert out.errors == ["no HEARTBEAT"]
    assert out.autopilot == ""
    assert closed(script)


def test_the_precision_landing_script_closes_its_links_too() -> None:
    script = silent_script(PrecLandScript)
    out = script.run_precland()
    assert out.errors == ["no HEARTBEAT"]
    assert closed(script)


def test_the_gap_script_closes_its_links_too() -> None:
    script = silent_script(GapScript)
    out = script.fly_gap(5.0)
    assert out.errors == ["no HEARTBEAT"]
    assert closed(script)
