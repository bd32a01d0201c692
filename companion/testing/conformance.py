"""One scripted flight, flown the same way against any vehicle, to compare autopilots.

Arm, take off, hand over to the companion's setpoints, descend slowly (0.26 m/s, below PX4's
land-detector threshold of 1.1 x LNDMC_Z_VEL_MAX), then at 0.33 m/s, and see whether and when the
vehicle says it has landed and disarms. It talks plain pymavlink, not the companion's link, so
what it records is the vehicle's behaviour, not ours: the same script against real PX4 SIH and
our SITL's PX4 personality (and real ArduCopter against our ArduPilot personality) gives the
conformance table of docs/link.md.

Every duration of the script (the descents, the waits for the climb and the disarm) and every time
it reports counts the vehicle's seconds (:mod:`companion.testing.vehicle_time`), so the script
means the same against an autopilot run faster than real time; only the waits for a command's
ACK or a parameter's value, and the safety limits, are on the wall clock.
"""

from __future__ import annotations

import json
import math
import tempfile
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Protocol, TypeVar

from pymavlink import mavutil

from companion.testing.vehicle_time import VehicleClock, wall_cap_s

M = mavutil.mavlink
NAN = math.nan
SETPOINT_PERIOD_S = 0.1  # of the vehicle's time: 10 Hz however fast it runs
READ_S = 0.02  # wall: the longest a read blocks, so a fast vehicle's time is followed closely
SLOW_DESCENT_M_S = 0.26
FAST_DESCENT_M_S = 0.33
TAKEOFF_ALT_M = 2.5
MODES = {  # (take-off mode, offboard mode) as pymavlink names them
    "PX4": ("LOITER", "OFFBOARD"),
    "ARDUPILOTMEGA": ("GUIDED", "GUIDED"),
}
LOSS_PARAMS = {  # the vehicle's own limit on a gap in the setpoint stream, in seconds of its time
    "PX4": "COM_OF_LOSS_T",  # leaves OFFBOARD for its hold (PX4's SITL scales it by its speed factor)
    "ARDUPILOTMEGA": "GUID_TIMEOUT",  # stops in GUIDED
}
MODE_HEARTBEAT_S = 5.0  # of the vehicle's time: the most to wait for a HEARTBEAT after the mode's ACK


@dataclass
class Outcome:
    """What the vehicle did at each step of the script (ACK result names, seconds of the vehicle's time)."""

    autopilot: str = ""
    land_param: dict[str, float | None] = field(default_factory=dict)
    takeoff_mode_ack: str = ""
    armable_after_s: float | None = None
    arm_refusals: list[str] = field(default_factory=list)
    takeoff_ack: str = ""
    climbed_m: float | None = None
    offboard_ack: str = ""
    mode_in_offboard: str = ""
    landed_at_slow_descent_s: float | None = None  # None: not within the slow phase
    landed_at_fast_descent_s: float | None = None
    disarmed: str = ""  # "by itself after N s", "on command: ACK", "no"
    standing_height_m: float | None = None  # -z of LOCAL_POSITION_NED while standing before arming
    home_z_m: float | None = None
    errors: list[str] = field(default_factory=list)
    loss_timeout_s: float | None = None  # the vehicle's LOSS_PARAMS value, as read
    max_setpoint_gap_s: float | None = None  # the longest the script left the stream, of the vehicle's time
    flights: int = 1  # the flight this is; an earlier one's setpoint stream broke (fly_script)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def stream_broke(self) -> bool:
        """The script itself left a gap in the setpoint stream as long as the vehicle's limit:
        then what the vehicle did measured the machine's load, not the autopilot."""
        gap, limit = self.max_setpoint_gap_s, self.loss_timeout_s
        return gap is not None and limit is not None and gap >= limit


class TextListener:
    """STATUSTEXT from a second link, on a thread, saying HEARTBEAT as a ground station: PX4 sends
    none on its onboard (API) link, and on its ground station link only to a peer it heard."""

    def __init__(self, connection: str) -> None:
        import threading

        self.texts: list[str] = []
        self._mav = mavutil.mavlink_connection(connection, source_system=247)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        next_beat = 0.0
        while not self._stop.is_set():
            if time.monotonic() >= next_beat:
                self._mav.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
                next_beat = time.monotonic() + 1.0
            msg = self._mav.recv_match(type="STATUSTEXT", blocking=True, timeout=0.2)
            if msg is not None and msg.get_srcComponent() == 1:
                self.texts.append(str(msg.text))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self._mav.close()


class Script:
    """The scripted flight on one MAVLink connection (and what the vehicle says, on it and, from
    ``texts_from``, on a second link)."""

    def __init__(self, connection: str, slow_s: float = 25.0, fast_s: float = 20.0,
                 texts_from: str | None = None, hello_timeout_s: float = 60.0) -> None:
        self.mav = mavutil.mavlink_connection(connection, source_system=246, source_component=191)
        self.hello_timeout_s = hello_timeout_s
        self.listener = TextListener(texts_from) if texts_from else None
        self._unheard: deque[str] = deque(maxlen=200)
        self.slow_s, self.fast_s = slow_s, fast_s
        self.out = Outcome()
        self.z = NAN
        self.landed = 0
        self.armed = False
        self.mode = ""
        self.home_z: float | None = None
        self.heartbeats = 0
        self.clock = VehicleClock()
        self._last_send_s: float | None = None  # of the vehicle's time: the stream's last setpoint

    # ----- plumbing ---------------------------------------------------------------------------
    def _pump(self, seconds: float, until: Any = None, wall: bool = False) -> Any:
        """Read messages for up to ``seconds`` of the vehicle's time (``wall``: of the wall clock,
        for an ACK or a parameter); return the first for which ``until`` is true."""
        start_v = self.clock.seconds
        deadline = time.monotonic() + (seconds if wall else wall_cap_s(seconds))
        while (left := deadline - time.monotonic()) > 0 and (wall or self.clock.seconds - start_v < seconds):
            msg = self.mav.recv_match(blocking=True, timeout=min(left, 0.2 if wall else READ_S))
            if msg is None:
                continue
            self._fold(msg)
            if until is not None and until(msg):
                return msg
        return None

    def _fold(self, msg: Any) -> None:
        kind = msg.get_type()
        if msg.get_srcComponent() != 1 and kind != "COMMAND_ACK":
            return
        if msg.get_srcComponent() == 1:
            self.clock.observe(msg)
        if kind == "LOCAL_POSITION_NED":
            self.z = float(msg.z)
        elif kind == "EXTENDED_SYS_STATE":
            self.landed = int(msg.landed_state)
        elif kind == "HOME_POSITION":
            self.home_z = float(msg.z)
        elif kind == "HEARTBEAT" and msg.type not in (M.MAV_TYPE_GCS, M.MAV_TYPE_ONBOARD_CONTROLLER):
            self.armed = bool(msg.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED)
            self.mode = mavutil.mode_string_v10(msg)
            self.heartbeats += 1
        elif kind == "STATUSTEXT":
            text = str(msg.text)
            self._unheard.append(text)
            if msg.severity <= M.MAV_SEVERITY_WARNING and text not in self.out.arm_refusals \
                    and len(self.out.arm_refusals) < 20:
                self.out.arm_refusals.append(text)

    def _heard(self) -> list[str]:
        """What the vehicle said since the last call, on this link and on the second one."""
        texts = list(self._unheard)
        self._unheard.clear()
        while self.listener is not None and self.listener.texts:
            texts.append(self.listener.texts.pop(0))
        return texts

    def _command(self, command: int, params: list[float], timeout_s: float = 3.0) -> str:
        padded = (params + [0.0] * 7)[:7]
        for attempt in range(3):
            self.mav.mav.command_long_send(self.mav.target_system, 1, command, attempt, *padded)
            ack = self._pump(timeout_s / 3, lambda m: m.get_type() == "COMMAND_ACK" and m.command == command, wall=True)
            if ack is not None:
                return str(M.enums["MAV_RESULT"][ack.result].name).removeprefix("MAV_RESULT_")
        return "NO_ACK"

    def _set_mode(self, name: str) -> str:
        mapping = self.mav.mode_mapping() or {}
        if name not in mapping:
            return f"UNKNOWN_MODE({name})"
        number = mapping[name]
        base = M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (M.MAV_MODE_FLAG_SAFETY_ARMED if self.armed else 0)
        if isinstance(number, tuple):  # PX4: (base, main, sub)
            return self._command(M.MAV_CMD_DO_SET_MODE, [float(base), float(number[1]), float(number[2])])
        return self._command(M.MAV_CMD_DO_SET_MODE, [float(base), float(number)])

    def _velocity(self, down_m_s: float) -> None:
        self.mav.mav.set_position_target_local_ned_send(
            0, self.mav.target_system, 1, M.MAV_FRAME_BODY_NED, 0x5C7,
            0.0, 0.0, 0.0, 0.0, 0.0, down_m_s, 0.0, 0.0, 0.0, 0.0, 0.0)

    def _stream(self, down_m_s: float, seconds: float, until: Any = None) -> float | None:
        """Stream a body velocity at 10 Hz for ``seconds``; seconds until ``until()`` (None: never)."""
        return self._at_10_hz(lambda: self._velocity(down_m_s), seconds, until)

    def _at_10_hz(self, send: Any, seconds: float, until: Any = None) -> float | None:
        """``send()`` every 0.1 s for ``seconds``, reading meanwhile; seconds until ``until()``.
        All of the vehicle's time: a vehicle run N times faster gets its setpoints N times as
        often on the wall clock, as many per second of its own as at real time."""
        start = next_send = self.clock.seconds
        deadline = time.monotonic() + wall_cap_s(seconds)
        while (elapsed := self.clock.seconds - start) < seconds and time.monotonic() < deadline:
            if self.clock.seconds >= next_send:
                send()
                self._note_sent()
                next_send = self.clock.seconds + SETPOINT_PERIOD_S
            self._read_one()
            if until is not None and until():
                return elapsed
        return None

    def _note_sent(self) -> None:
        """The gap since the stream's last setpoint (across the script's steps: a mode's ACK
        awaited without streaming counts too), the longest kept in the outcome."""
        now = self.clock.seconds
        if self._last_send_s is not None:
            gap = round(now - self._last_send_s, 3)
            self.out.max_setpoint_gap_s = max(gap, self.out.max_setpoint_gap_s or 0.0)
        self._last_send_s = now

    def _read_one(self) -> None:
        """Fold the next message, waiting at most :data:`READ_S` of wall time for it."""
        msg = self.mav.recv_match(blocking=True, timeout=READ_S)
        if msg is not None:
            self._fold(msg)

    def _param(self, name: str, attempts: int = 4) -> float | None:
        """PARAM_REQUEST_READ, asked again when no answer comes within 3 s: over UDP a request
        or its PARAM_VALUE can be lost, and a starved autopilot answers late."""
        for _ in range(attempts):
            self.mav.mav.param_request_read_send(self.mav.target_system, 1, name.encode(), -1)
            msg = self._pump(3.0, lambda m: m.get_type() == "PARAM_VALUE" and m.param_id == name, wall=True)
            if msg is not None:
                return float(msg.param_value)
        return None

    def _hello(self, errors: list[str]) -> str | None:
        """Wait for the vehicle's HEARTBEAT: its autopilot's name (``PX4``, ``ARDUPILOTMEGA``), or
        None with the reason added to ``errors`` and the links closed (the script ends there)."""
        hb = self.mav.wait_heartbeat(timeout=self.hello_timeout_s)
        if hb is None:
            errors.append("no HEARTBEAT")
            self._close()
            return None
        return str(M.enums["MAV_AUTOPILOT"][hb.autopilot].name).removeprefix("MAV_AUTOPILOT_")

    def _stream_rates(self, rates: Iterable[tuple[str, float]]) -> None:
        """Ask for each message (its name) at its rate in Hz."""
        for message, hz in rates:
            self._command(M.MAV_CMD_SET_MESSAGE_INTERVAL, [float(getattr(M, f"MAVLINK_MSG_ID_{message}")), 1e6 / hz])

    # ----- the script -------------------------------------------------------------------------
    def run(self, armable_timeout_s: float = 120.0) -> Outcome:
        out = self.out
        autopilot = self._hello(out.errors)
        if autopilot is None:
            return out
        out.autopilot = autopilot
        takeoff_mode, offboard_mode = MODES.get(out.autopilot, ("", ""))
        # ATTITUDE: a stamped message from the start (ArduCopter sends no position before its EKF has one)
        self._stream_rates((("LOCAL_POSITION_NED", 20), ("EXTENDED_SYS_STATE", 5), ("HOME_POSITION", 1), ("ATTITUDE", 10)))
        names = ("LNDMC_Z_VEL_MAX",) if out.autopilot == "PX4" else ("LAND_SPEED", "LAND_SPEED_HIGH")
        out.land_param = {n: self._param(n) for n in names}
        if out.autopilot in LOSS_PARAMS:
            out.loss_timeout_s = self._param(LOSS_PARAMS[out.autopilot])
        self._arm(takeoff_mode, armable_timeout_s)
        if not self.armed:
            out.errors.append("never armed")
            return self._finish()
        if out.autopilot == "PX4":
            self.mav.mav.param_set_send(self.mav.target_system, 1, b"MIS_TAKEOFF_ALT", TAKEOFF_ALT_M, M.MAV_PARAM_TYPE_REAL32)
            self._pump(0.5)
            out.takeoff_ack = self._command(M.MAV_CMD_NAV_TAKEOFF, [-1.0, 0.0, 0.0, NAN, NAN, NAN, NAN])
        else:
            out.takeoff_ack = self._command(M.MAV_CMD_NAV_TAKEOFF, [0.0, 0.0, 0.0, NAN, 0.0, 0.0, TAKEOFF_ALT_M])
        ground_z = self.z
        self._pump(15.0, lambda m: m.get_type() == "LOCAL_POSITION_NED" and ground_z - m.z > 0.9 * TAKEOFF_ALT_M)
        self._pump(2.0)
        out.climbed_m = round(ground_z - self.z, 2)
        self._stream(0.0, 1.0)  # a fresh stream first: PX4 refuses OFFBOARD without one
        out.offboard_ack = self._set_mode(offboard_mode)
        acked_at = self.heartbeats
        self._stream(0.0, 1.5)
        if self.heartbeats == acked_at:  # the mode is what a HEARTBEAT sent after the ACK says
            self._stream(0.0, MODE_HEARTBEAT_S, lambda: self.heartbeats > acked_at)
        out.mode_in_offboard = self.mode if self.heartbeats > acked_at else f"no HEARTBEAT (last: {self.mode})"
        on_ground = lambda: self.landed == M.MAV_LANDED_STATE_ON_GROUND  # noqa: E731
        out.landed_at_slow_descent_s = _rounded(self._stream(SLOW_DESCENT_M_S, self.slow_s, on_ground))
        if out.landed_at_slow_descent_s is None:
            out.landed_at_fast_descent_s = _rounded(self._stream(FAST_DESCENT_M_S, self.fast_s, on_ground))
        return self._finish()

    def _arm(self, takeoff_mode: str, timeout_s: float) -> None:
        out = self.out
        start = self.clock.seconds
        deadline = time.monotonic() + wall_cap_s(timeout_s)
        self._pump(1.0)
        out.standing_height_m = None if math.isnan(self.z) else round(-self.z, 3)
        out.home_z_m = None if self.home_z is None else round(self.home_z, 3)
        while self.clock.seconds - start < timeout_s and time.monotonic() < deadline:
            ack = self._set_mode(takeoff_mode)
            out.takeoff_mode_ack = out.takeoff_mode_ack or ack
            if ack == "ACCEPTED" and self._command(M.MAV_CMD_COMPONENT_ARM_DISARM, [1.0]) == "ACCEPTED":
                self._pump(1.5)
                if self.armed and self.mode == takeoff_mode:
                    out.takeoff_mode_ack = ack
                    out.armable_after_s = round(self.clock.seconds - start, 1)
                    return
            self._pump(1.0)

    def _finish(self) -> Outcome:
        out = self.out
        start = self.clock.seconds
        if self.armed:
            self._pump(20.0, lambda m: not self.armed)
        if not self.armed:
            out.disarmed = f"by itself after {self.clock.seconds - start:.0f} s"
        else:
            out.disarmed = "on command: " + self._command(M.MAV_CMD_COMPONENT_ARM_DISARM, [0.0])
            if out.disarmed.endswith("ACCEPTED"):
                self._pump(2.0)
            else:
                self._command(M.MAV_CMD_NAV_LAND, [0.0, 0.0, 0.0, NAN, NAN, NAN, NAN])
        self._close()
        return out

    def _close(self) -> None:
        """Close the vehicle's link and the second link's listener."""
        self.mav.close()
        if self.listener is not None:
            self.listener.close()


def _rounded(value: float | None) -> float | None:
    return None if value is None else round(value, 1)


def fly_script(connection: str, slow_s: float = 25.0, fast_s: float = 20.0, attempts: int = 2) -> Outcome:
    """The script against the vehicle at ``connection``, flown again (up to ``attempts``
    flights) when its own setpoint stream broke (:meth:`Outcome.stream_broke`).

    PX4 SIH at 4x leaves OFFBOARD after COM_OF_LOSS_T = 4 s of its time without a setpoint, 1 s
    of the wall: on a loaded machine (CI, load 19) real PX4 was once in LOITER where our SITL
    stayed in OFFBOARD (bench/results/ci-fresh-2026-12-07-35-failed.txt). A flight with such a
    gap measured the machine; the outcome keeps the gap and the count in ``flights``."""
    return flown_until_whole(lambda: Script(connection, slow_s, fast_s).run(), Outcome.stream_broke, attempts)


class _Flight(Protocol):
    flights: int


FlightT = TypeVar("FlightT", bound=_Flight)


def flown_until_whole(fly: Callable[[], FlightT], broke: Callable[[FlightT], bool], attempts: int) -> FlightT:
    """``fly()``, again (up to ``attempts`` flights) while ``broke`` says the script's own stream
    to the vehicle broke: such a flight measured the machine's load, not the autopilot. The
    outcome returned keeps its count in ``flights``."""
    for flight in range(1, attempts + 1):
        outcome = fly()
        outcome.flights = flight
        if not broke(outcome):
            break
    return outcome


COMPARED = ("takeoff_mode_ack", "takeoff_ack", "offboard_ack", "mode_in_offboard")


def differences(real: Outcome, ours: Outcome) -> list[str]:
    """Where our SITL's outcome differs from the real autopilot's in what the companion relies
    on: the ACKs, the mode it flies in, whether the slow and the fast descent end in a landed
    state, and whether it then disarms by itself (times are reported, not compared)."""
    diffs = [f"{name}: real {getattr(real, name)!r}, ours {getattr(ours, name)!r}"
             for name in COMPARED if getattr(real, name) != getattr(ours, name)]
    for name in ("landed_at_slow_descent_s", "landed_at_fast_descent_s"):
        r, o = getattr(real, name) is not None, getattr(ours, name) is not None
        if r != o:
            diffs.append(f"{name}: real {'landed' if r else 'not landed'}, ours {'landed' if o else 'not landed'}")
    if real.disarmed.split(" after")[0] != ours.disarmed.split(" after")[0]:
        diffs.append(f"disarmed: real {real.disarmed!r}, ours {ours.disarmed!r}")
    return diffs


def in_parallel(names: Iterable[str], fly: Callable[[str], None]) -> None:
    """``fly(name)`` for each name on a thread of its own, all at once; return when all are done."""
    threads = [threading.Thread(target=fly, args=(name,)) for name in names]
    for t in threads:
        t.start()
    for t in threads:
        t.join()


def autopilots_and_work(prefix: str) -> tuple[Path, Path, Path]:
    """The real autopilots' folder (or exit saying how to get them), a fresh work folder, and in
    it our SITL's config for these comparisons (a PX4-like pre-arm settling of 4 s)."""
    from companion.testing.autopilots import find_autopilots

    root, why = find_autopilots()
    if root is None:
        raise SystemExit(why)
    work = Path(tempfile.mkdtemp(prefix=prefix))
    config = work / "sitl.toml"
    config.write_text("[sitl.personality]\nprearm_settle_s = 4.0\n")
    return root, work, config


def print_report(report: dict[str, Any], out: Path | None) -> None:
    """Print ``report`` as JSON, and write it to ``out`` too when given."""
    text = json.dumps(report, indent=1)
    if out:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(text + "\n")
    print(text)


def main() -> None:
    """Fly the script against real PX4 SIH, real ArduCopter and our SITL as each, side by side,
    and print one JSON object: each outcome and the differences (docs/link.md's table)."""
    import argparse

    from companion.simulator import start_sitl
    from companion.testing.autopilots import (
        free_udp_port,
        start_ardupilot,
        start_px4,
    )

    parser = argparse.ArgumentParser(description=main.__doc__)
    parser.add_argument("--out", type=Path, help="also write the JSON here")
    for kind in ("px4", "ardupilot"):
        parser.add_argument(f"--{kind}-speedup", type=float, default=1.0,
                            help=f"real {kind} and our SITL as it this many times real time (the script counts their time)")
    args = parser.parse_args()
    speedup = {"px4": args.px4_speedup, "ardupilot": args.ardupilot_speedup}
    root, work, config = autopilots_and_work("conformance-")
    connections: dict[str, str] = {}
    stops = []
    for kind, start in (("real px4", start_px4), ("real ardupilot", start_ardupilot)):
        ap = start(root, work / kind.replace(" ", "-"), speedup=speedup[kind.split()[1]])
        connections[kind] = ap.connection
        stops.append(ap.stop)
    for personality in ("px4", "ardupilot"):
        port = free_udp_port()
        sitl = start_sitl(port, clock="realtime", config=config, camera=False, timeout_s=120.0,
                          extra_args=["--autopilot", personality, "--speed", f"{speedup[personality]:g}"])
        connections[f"ours {personality}"] = f"udpin:127.0.0.1:{port}"
        stops.append(sitl.stop)
    outcomes: dict[str, Outcome] = {}

    def fly(name: str) -> None:
        outcomes[name] = fly_script(connections[name])

    try:
        in_parallel(connections, fly)
    finally:
        for stop in stops:
            stop()
    print_report({"outcomes": {k: v.to_dict() for k, v in sorted(outcomes.items())},
                  "differences": {p: differences(outcomes[f"real {p}"], outcomes[f"ours {p}"]) for p in ("px4", "ardupilot")}},
                  args.out)


if __name__ == "__main__":
    main()


# ----- precision landing ------------------------------------------------------------------------
PRECLAND_POINT_NE_M = (3.0, 2.0)  # the fixed point to land on, from where the vehicle took off
PRECLAND_ALT_M = 4.0
STREAM_BROKEN = "PrecLand: Init Failed"  # ArduCopter: no LANDING_TARGET for 0.5 s of its time while it initialised
PX4_PRECLAND_PARAMS = ("PLD_BTOUT", "PLD_HACC_RAD", "PLD_FAPPR_ALT", "PLD_SRCH_ALT", "PLD_SRCH_TOUT", "PLD_MAX_SRCH",
                       "LTEST_MODE", "LTEST_ACC_UNC", "LTEST_MEAS_UNC", "LTEST_SCALE_X", "LTEST_SENS_ROT")
AP_PRECLAND_PARAMS = ("PLND_ENABLED", "PLND_TYPE", "PLND_EST_TYPE", "PLND_LAG", "PLND_XY_DIST_MAX", "PLND_STRICT",
                      "PLND_RET_MAX", "PLND_TIMEOUT", "PLND_ALT_MIN", "PLND_ALT_MAX", "PLND_OPTIONS", "PLND_ORIENT")


PRECLAND_RATES = (("LOCAL_POSITION_NED", 20.0), ("EXTENDED_SYS_STATE", 5.0), ("ATTITUDE", 20.0))  # message, Hz


@dataclass
class PrecLandOutcome:
    """What a vehicle did with LANDING_TARGET toward a fixed point and a precision landing request."""

    autopilot: str = ""
    params: dict[str, float | None] = field(default_factory=dict)
    reboot_ack: str = ""  # ArduPilot: PLND_TYPE takes effect at boot
    armed: bool = False
    climbed_m: float | None = None
    mode_ack: str = ""
    mode_in_heartbeat: str = ""
    landed_after_s: float | None = None
    touchdown_from_point_m: float | None = None  # horizontal, in the vehicle's own local frame
    start_from_point_m: float | None = None
    wrong_frame_texts: list[str] = field(default_factory=list)  # said after targets in the other autopilot's frame
    texts: list[str] = field(default_factory=list)  # what it said meanwhile
    errors: list[str] = field(default_factory=list)
    flights: int = 1  # the flight this is; an earlier one's target stream broke (fly_precland)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


class PrecLandScript(Script):
    """Take off, send LANDING_TARGET for a fixed point 3 m north, 2 m east of the take-off place
    (PX4: LOCAL_NED; ArduPilot: BODY_FRD, from the vehicle's own reported position and attitude),
    ask for precision landing (PX4: AUTO.PRECLAND; ArduPilot: PLND on, LAND) and see where it lands."""

    def __init__(self, connection: str, land_s: float = 60.0, texts_from: str | None = None) -> None:
        super().__init__(connection, texts_from=texts_from)
        self.land_s = land_s
        self.pr = PrecLandOutcome()
        self.xy = (NAN, NAN)
        self.attitude = (0.0, 0.0, 0.0)
        self.custom_mode = 0

    def _fold(self, msg: Any) -> None:
        super()._fold(msg)
        if msg.get_srcComponent() != 1:
            return
        kind = msg.get_type()
        if kind == "LOCAL_POSITION_NED":
            self.xy = (float(msg.x), float(msg.y))
        elif kind == "ATTITUDE":
            self.attitude = (float(msg.roll), float(msg.pitch), float(msg.yaw))
        elif kind == "HEARTBEAT" and msg.type not in (M.MAV_TYPE_GCS, M.MAV_TYPE_ONBOARD_CONTROLLER):
            self.custom_mode = int(msg.custom_mode)

    def _said(self, text: str) -> None:
        if len(self.pr.texts) < 40 and text not in self.pr.texts:
            self.pr.texts.append(text)

    def _pump(self, seconds: float, until: Any = None, wall: bool = False) -> Any:
        found = super()._pump(seconds, until, wall)
        self._heard_texts()
        return found

    def _read_one(self) -> None:
        super()._read_one()
        self._heard_texts()

    def _heard_texts(self) -> None:
        for text in self._heard():
            self._said(text)

    def _target(self, point: tuple[float, float, float], wrong_frame: bool = False) -> None:
        from sitl.landing_target import FRAME_BODY_FRD, FRAME_LOCAL_NED, ned_to_body

        rel = (point[0] - self.xy[0], point[1] - self.xy[1], point[2] - self.z)
        distance = math.sqrt(sum(c * c for c in rel))
        body = ned_to_body(rel, self.attitude)
        angles = (math.atan2(body[1], body[2]), math.atan2(-body[0], body[2]))
        frame, xyz = (FRAME_LOCAL_NED, point) if (self.pr.autopilot == "PX4") != wrong_frame else (FRAME_BODY_FRD, body)
        self.mav.mav.landing_target_send(int(time.monotonic() * 1e6), 0, frame, *angles, distance, 0.1, 0.1, *xyz,
                                         [1.0, 0.0, 0.0, 0.0], M.LANDING_TARGET_TYPE_VISION_FIDUCIAL, 1)

    def _send_targets(self, point: tuple[float, float, float], seconds: float, until: Any = None) -> float | None:
        return self._at_10_hz(lambda: self._target(point), seconds, until)

    def run_precland(self, armable_timeout_s: float = 120.0) -> PrecLandOutcome:
        pr = self.pr
        autopilot = self._hello(pr.errors)
        if autopilot is None:
            return pr
        pr.autopilot = autopilot
        px4 = pr.autopilot == "PX4"
        self._stream_rates(PRECLAND_RATES)
        if not px4:
            self._plnd_on_and_reboot()
        pr.params = {n: self._param(n) for n in (PX4_PRECLAND_PARAMS if px4 else AP_PRECLAND_PARAMS)}
        takeoff_mode = MODES.get(pr.autopilot, ("", ""))[0]
        self._arm(takeoff_mode, armable_timeout_s)
        pr.armed = self.armed
        if not self.armed:
            pr.errors.append("never armed")
            return self._finish_precland()
        ground = (self.xy[0], self.xy[1], self.z)
        self._take_off(px4)
        pr.climbed_m = round(ground[2] - self.z, 2)
        point = (ground[0] + PRECLAND_POINT_NE_M[0], ground[1] + PRECLAND_POINT_NE_M[1], ground[2])
        pr.start_from_point_m = round(math.hypot(point[0] - self.xy[0], point[1] - self.xy[1]), 2)
        said = len(pr.texts)
        for _ in range(3):
            self._target(point, wrong_frame=True)
            self._pump(0.2)
        self._wait_for_text(said, "rame")
        pr.wrong_frame_texts = pr.texts[said:]
        self._send_targets(point, 1.5)
        pr.mode_ack = self._precland_mode(px4)
        self._send_targets(point, 1.5)
        c = self.custom_mode
        pr.mode_in_heartbeat = f"{self.mode} (main {(c >> 16) & 0xFF}, sub {(c >> 24) & 0xFF})" if px4 else self.mode
        on_ground = lambda: self.landed == M.MAV_LANDED_STATE_ON_GROUND or not self.armed  # noqa: E731
        landed = self._send_targets(point, self.land_s, on_ground)
        pr.landed_after_s = None if landed is None else round(landed + 3.0, 1)
        if landed is not None:
            pr.touchdown_from_point_m = round(math.hypot(point[0] - self.xy[0], point[1] - self.xy[1]), 2)
        return self._finish_precland()

    def _wait_for_text(self, said: int, part: str, vehicle_s: float = 1.0, wall_s: float = 4.0) -> None:
        """Read on until a text said after the first ``said`` holds ``part``, for at least
        ``vehicle_s`` of the vehicle's time and ``wall_s`` of the wall's: PX4's texts come on a
        second link, read by a thread that a loaded machine can hold back longer than a fast
        vehicle takes for a second."""
        start_v, deadline = self.clock.seconds, time.monotonic() + wall_s
        while not any(part in text for text in self.pr.texts[said:]):
            if self.clock.seconds - start_v >= vehicle_s and time.monotonic() >= deadline:
                return
            self._pump(0.1)

    def _plnd_on_and_reboot(self) -> None:
        """PLND_ENABLED = 1, PLND_TYPE = 1 (MAVLink), then a reboot: ArduCopter makes its
        precision landing backend at boot (set at run time only, LAND lands vertically)."""
        for name in ("PLND_ENABLED", "PLND_TYPE"):
            self.mav.mav.param_set_send(self.mav.target_system, 1, name.encode(), 1.0, M.MAV_PARAM_TYPE_INT8)
            self._pump(0.5)
        self.pr.reboot_ack = self._command(M.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, [1.0])
        self._pump(3.0, wall=True)  # its process restarting, on the wall clock: then no HEARTBEAT of before it is read
        self.mav.wait_heartbeat(timeout=60)
        self._stream_rates(PRECLAND_RATES)

    def _precland_mode(self, px4: bool) -> str:
        """PX4: DO_SET_MODE AUTO (4) / PRECLAND (9), a mode pymavlink has no name for; ArduPilot: LAND."""
        if not px4:
            return self._set_mode("LAND")
        base = M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (M.MAV_MODE_FLAG_SAFETY_ARMED if self.armed else 0)
        return self._command(M.MAV_CMD_DO_SET_MODE, [float(base), 4.0, 9.0])

    def _take_off(self, px4: bool) -> None:
        if px4:
            self.mav.mav.param_set_send(self.mav.target_system, 1, b"MIS_TAKEOFF_ALT", PRECLAND_ALT_M, M.MAV_PARAM_TYPE_REAL32)
            self._pump(0.5)
            self._command(M.MAV_CMD_NAV_TAKEOFF, [-1.0, 0.0, 0.0, NAN, NAN, NAN, NAN])
        else:
            self._command(M.MAV_CMD_NAV_TAKEOFF, [0.0, 0.0, 0.0, NAN, 0.0, 0.0, PRECLAND_ALT_M])
        ground_z = self.z
        self._pump(20.0, lambda m: m.get_type() == "LOCAL_POSITION_NED" and ground_z - m.z > 0.9 * PRECLAND_ALT_M)
        self._pump(2.0)

    def _finish_precland(self) -> PrecLandOutcome:
        self._finish()
        return self.pr


def fly_precland(connection: str, land_s: float = 60.0, texts_from: str | None = None,
                 attempts: int = 2) -> PrecLandOutcome:
    """The precision-landing script against the vehicle at ``connection`` (STATUSTEXT also from
    ``texts_from``, a second link, if given), flown again (up to ``attempts`` flights) when the
    vehicle said our target stream broke (:data:`STREAM_BROKEN`).

    ArduCopter's estimator needs a LANDING_TARGET at least every 0.5 s of its time for its first
    2 s (AC_PrecLand's EKF_INIT_SENSOR_MIN_UPDATE_MS), else it says "PrecLand: Init Failed". At 5x
    that is 0.1 s of the wall: a script stalled that long by a loaded machine broke the stream,
    and ArduCopter landed where it stood (bench/results/ci-fresh-2026-12-07-32-failed.txt). That
    flight measured the machine, not the autopilot; the outcome keeps the count in ``flights``."""
    return flown_until_whole(lambda: PrecLandScript(connection, land_s, texts_from).run_precland(),
                             lambda outcome: STREAM_BROKEN in outcome.texts, attempts)

