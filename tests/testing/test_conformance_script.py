"""The conformance scripts' opening against silence: they say why they stopped and leave nothing open."""

from __future__ import annotations

import pytest

from companion.testing.conformance import Outcome, PrecLandScript, Script, fly_script
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


def test_the_longest_gap_in_the_setpoint_stream_is_kept_on_the_vehicles_clock() -> None:
    script = Script(f"udpin:127.0.0.1:{free_port()}")
    try:
        for vehicle_s in (10.0, 10.1, 10.2, 11.45, 11.55):  # a mode's ACK awaited between 10.2 and 11.45
            script.clock.seconds = vehicle_s
            script._note_sent()
    finally:
        script.mav.close()
    out = script.out
    assert out.max_setpoint_gap_s == 1.25
    out.loss_timeout_s = 4.0  # PX4 SIH at 4x
    assert not out.stream_broke()
    out.loss_timeout_s = 1.0
    assert out.stream_broke()
    out.loss_timeout_s = None  # unread: nothing to judge by
    assert not out.stream_broke()


def test_a_flight_whose_own_stream_broke_is_flown_again_and_counted(monkeypatch: pytest.MonkeyPatch) -> None:
    flown: list[Outcome] = []
    gaps = iter([5.0, 0.3, 0.2])  # the first flight stalled past COM_OF_LOSS_T = 4 s

    def run(self: Script, armable_timeout_s: float = 120.0) -> Outcome:
        self.mav.close()
        self.out.loss_timeout_s, self.out.max_setpoint_gap_s = 4.0, next(gaps)
        flown.append(self.out)
        return self.out

    monkeypatch.setattr(Script, "run", run)
    out = fly_script(f"udpin:127.0.0.1:{free_port()}")
    assert len(flown) == 2 and out is flown[1] and out.flights == 2 and out.max_setpoint_gap_s == 0.3
    gaps = iter([5.0, 6.0])
    flown.clear()
    out = fly_script(f"udpin:127.0.0.1:{free_port()}", attempts=2)
    assert len(flown) == 2 and out.flights == 2 and out.stream_broke()  # still broken: kept and shown
