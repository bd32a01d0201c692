"""What a PX4 vehicle does when the offboard setpoints stop for a while and then come back.

A companion on a loaded machine, or on a radio that drops a burst, leaves gaps in its setpoint
stream. The script takes off, enters OFFBOARD on a stream of zero velocity, stops sending for
``gap_s`` of the vehicle's time, then streams again for :data:`AFTER_S`, and records every mode
the HEARTBEAT shows meanwhile (asked for at :data:`HEARTBEAT_HZ`) and what the vehicle says. Run
against real PX4 SIH and our SITL as PX4 side by side, it says when each gives OFFBOARD up and
whether it takes it back (``python -m companion.testing.setpoint_gap --out FILE``).
"""

from __future__ import annotations

import argparse
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from companion.testing.conformance import (
    MODES,
    NAN,
    TAKEOFF_ALT_M,
    M,
    Script,
    autopilots_and_work,
    in_parallel,
    print_report,
)

AFTER_S = 12.0  # of the vehicle's time: streaming again after the gap
HEARTBEAT_HZ = 10.0  # PX4 and our SITL send HEARTBEAT at 1 Hz unless asked: a short failsafe would go unseen
DEFAULT_GAPS_S = (0.7, 2.0, 7.0)


@dataclass
class GapOutcome:
    """The modes a vehicle showed from the gap's start (seconds of its time, mode name)."""

    gap_s: float
    loss_t_s: float | None = None  # COM_OF_LOSS_T as the vehicle read it back
    offboard_ack: str = ""
    modes: list[tuple[float, str]] = field(default_factory=list)
    texts: list[tuple[float, str]] = field(default_factory=list)  # said from the gap's start
    errors: list[str] = field(default_factory=list)

    @property
    def left_offboard(self) -> bool:
        return any(mode != "OFFBOARD" for _, mode in self.modes)

    @property
    def back_in_offboard(self) -> bool:
        return self.left_offboard and self.modes[-1][1] == "OFFBOARD"

    def to_dict(self) -> dict[str, Any]:
        return asdict(self) | {"left_offboard": self.left_offboard, "back_in_offboard": self.back_in_offboard}


class GapScript(Script):
    """Take off, OFFBOARD, a gap in the setpoints, the stream again."""

    def __init__(self, connection: str, texts_from: str | None = None, loss_t_s: float | None = None) -> None:
        super().__init__(connection, texts_from=texts_from)
        self.loss_t_s = loss_t_s

    def fly_gap(self, gap_s: float, armable_timeout_s: float = 120.0) -> GapOutcome:
        out = GapOutcome(gap_s)
        if self._hello(out.errors) is None:
            return out
        self._stream_rates((("LOCAL_POSITION_NED", 20), ("EXTENDED_SYS_STATE", 5), ("ATTITUDE", 10), ("HEARTBEAT", HEARTBEAT_HZ)))
        if self.loss_t_s is not None:
            self.mav.mav.param_set_send(self.mav.target_system, 1, b"COM_OF_LOSS_T", self.loss_t_s, M.MAV_PARAM_TYPE_REAL32)
        out.loss_t_s = self._param("COM_OF_LOSS_T")
        takeoff_mode, offboard_mode = MODES["PX4"]
        self._arm(takeoff_mode, armable_timeout_s)
        if not self.armed:
            out.errors.append("never armed")
            return self._done(out)
        self.mav.mav.param_set_send(self.mav.target_system, 1, b"MIS_TAKEOFF_ALT", TAKEOFF_ALT_M, M.MAV_PARAM_TYPE_REAL32)
        self._pump(0.5)
        self._command(M.MAV_CMD_NAV_TAKEOFF, [-1.0, 0.0, 0.0, NAN, NAN, NAN, NAN])
        ground_z = self.z
        self._pump(15.0, lambda m: m.get_type() == "LOCAL_POSITION_NED" and ground_z - m.z > 0.9 * TAKEOFF_ALT_M)
        self._stream(0.0, 1.0)
        out.offboard_ack = self._set_mode(offboard_mode)
        self._stream(0.0, 1.5)
        start = self.clock.seconds
        self._heard()

        def note() -> bool:
            """Record a mode change and what was said; never ends the phase."""
            now = round(self.clock.seconds - start, 2)
            if not out.modes or out.modes[-1][1] != self.mode:
                out.modes.append((now, self.mode))
            out.texts.extend((now, text) for text in self._heard())
            return False

        note()
        self._at_10_hz(lambda: None, gap_s, note)  # silent: read and note only
        self._at_10_hz(lambda: self._velocity(0.0), AFTER_S, note)
        return self._done(out)

    def _done(self, out: GapOutcome) -> GapOutcome:
        if self.armed:
            self._command(M.MAV_CMD_NAV_LAND, [0.0, 0.0, 0.0, NAN, NAN, NAN, NAN])
        self._finish()
        return out


def fly_gap(connection: str, gap_s: float, texts_from: str | None = None, loss_t_s: float | None = None) -> GapOutcome:
    """The gap script once against the PX4 vehicle at ``connection`` (STATUSTEXT also from
    ``texts_from``: PX4 says its failsafes on its ground station link only; COM_OF_LOSS_T set
    to ``loss_t_s`` first, if given)."""
    return GapScript(connection, texts_from, loss_t_s).fly_gap(gap_s)


def fly_pair(root: Path, work: Path, config: Path, gap_s: float, speedup: float,
             loss_t_s: float | None = None) -> dict[str, GapOutcome]:
    """A fresh real PX4 SIH and our SITL as PX4, the gap script against both at once."""
    from companion.simulator import start_sitl
    from companion.testing.autopilots import PX4_LOCAL_PORTS, free_udp_port, start_px4

    real = start_px4(root, work / f"px4-{gap_s:g}", speedup=speedup)
    port = free_udp_port()
    ours = start_sitl(port, clock="realtime", config=config, camera=False, timeout_s=120.0,
                      extra_args=["--autopilot", "px4", "--speed", f"{speedup:g}"])
    connections = {"real px4": real.connection, "ours px4": f"udpin:127.0.0.1:{port}"}
    texts_from = {"real px4": f"udpout:127.0.0.1:{PX4_LOCAL_PORTS[1] + real.instance}"}
    outcomes: dict[str, GapOutcome] = {}

    def fly(name: str) -> None:
        try:
            outcomes[name] = fly_gap(connections[name], gap_s, texts_from.get(name), loss_t_s)
        except Exception as exc:  # reported in the file
            outcomes[name] = GapOutcome(gap_s, errors=[repr(exc)])

    try:
        in_parallel(connections, fly)
    finally:
        real.stop()
        ours.stop()
    return outcomes


def main() -> None:
    """Fly the gap script against real PX4 SIH and our SITL as PX4, side by side, a fresh pair
    for each gap, and print one JSON object (each outcome, by gap)."""

    parser = argparse.ArgumentParser(description=main.__doc__)
    parser.add_argument("--gaps", type=float, nargs="+", default=list(DEFAULT_GAPS_S), help="seconds of the vehicle's time")
    parser.add_argument("--speedup", type=float, default=2.0, help="real PX4 and our SITL this many times real time")
    parser.add_argument("--loss-t", type=float, help="set COM_OF_LOSS_T to this first (default: leave each vehicle's own)")
    parser.add_argument("--out", type=Path, help="also write the JSON here")
    args = parser.parse_args()
    root, work, config = autopilots_and_work("setpoint-gap-")
    report: dict[str, Any] = {"speedup": args.speedup, "loss_t_set": args.loss_t, "after_s": AFTER_S, "heartbeat_hz": HEARTBEAT_HZ, "gaps": []}
    for gap in args.gaps:
        outcomes = fly_pair(root, work, config, gap, args.speedup, args.loss_t)
        report["gaps"].append({name: outcomes[name].to_dict() for name in sorted(outcomes)})
        print(f"gap {gap:g} s: " + "; ".join(f"{n} {outcomes[n].modes}" for n in sorted(outcomes)), flush=True)
    print_report(report, args.out)


if __name__ == "__main__":
    main()
