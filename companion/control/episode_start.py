"""How an episode starts: reset by the simulator, or flown to a start point as on a real
vehicle, then handed to offboard control the way the vehicle's autopilot wants it.

With a simulator's control surface (our SITL) the episode is a reset: the vehicle is put at the
episode's start, holding, and the first frame after it that reports it in the air is the
episode's first. Without one (a real autopilot) the vehicle is armed, takes off and flies to a
random start above the pad with position setpoints. Then offboard: PX4 wants a fresh setpoint
stream before OFFBOARD, ArduPilot wants GUIDED before it streams (companion/link/dialect.py).
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Callable
from typing import Protocol

import numpy as np

from companion.config import SessionConfig
from companion.control.link_port import HOLD, LinkPort
from companion.control.precland import PrecisionLander
from companion.control.sequences import arm_when_ready, streaming, take_off, when_ready
from companion.control.truth_contact import TruthGround
from companion.errors import ColError, CommandRejected, LinkError
from companion.link.dialect import Dialect
from companion.link.sim_params import AutopilotSim
from companion.link.truth import ask_for_truth
from companion.msg.snapshot import VehicleSnapshot
from companion.simulator import SimulatorClient

log = logging.getLogger(__name__)
OFFBOARD_ATTEMPTS = 3
RETRY_STREAM_FRAMES = 5  # after a refusal: half a second of setpoints, so a lossy link delivers some
TELEMETRY_FRAMES = 100  # frames after a reset within which the vehicle must report being in the air
TRUTH_FRAMES = 50  # frames to wait for the SITL's first truth while the vehicle stands (about 5 s)
TAKEOFF_ATTEMPTS = 2  # a vehicle that disarmed itself as it took off is taken off once more


class StartParts(Protocol):
    """What a start needs of the session's parts (read at each start: a run may swap them)."""

    cfg: SessionConfig
    simulator: SimulatorClient | None
    lander: PrecisionLander | None
    truth_rate_hz: float
    autopilot_sim: AutopilotSim | None


class EpisodeStart:
    """Starts episodes on one vehicle through its :class:`LinkPort` (module docstring)."""

    def __init__(self, port: LinkPort, parts: StartParts, dialect: Callable[[], Dialect],
                 truth_ground: TruthGround | None = None) -> None:
        self.port, self.parts, self._dialect = port, parts, dialect
        self.truth_ground = truth_ground
        """Where a SITL's truth puts the ground, measured before each take-off (None: not asked)."""
        self._asked_truth = False
        self._precland_prepared = False  # the lander's boot-time parameters checked (and rebooted for)
        self._warned_home = False

    @property
    def dialect(self) -> Dialect:
        return self._dialect()

    @property
    def cfg(self) -> SessionConfig:
        return self.parts.cfg

    @property
    def simulator(self) -> SimulatorClient | None:
        return self.parts.simulator

    @property
    def lander(self) -> PrecisionLander | None:
        return self.parts.lander

    def start(self, seed: int | None) -> tuple[VehicleSnapshot, list[str]]:
        """The episode's first snapshot, in offboard control, and notes for its record."""
        notes: list[str] = []
        self._prepare_precland(notes)
        if self.simulator is not None:
            reply = self.simulator.reset(seed)
            self.port.frame_ms = int(reply["time_boot_ms"])
            snap = self._wait_telemetry_after(self.port.frame_ms)
        else:
            snap = self._fly_to_start(seed, notes)
            notes.append("started by flying to the start point")
        return self.ensure_offboard(snap, mode_known=self.simulator is None), notes

    # ----- offboard ------------------------------------------------------------------------------
    def ensure_offboard(self, snap: VehicleSnapshot, mode_known: bool = True) -> VehicleSnapshot:
        """Enter the dialect's offboard mode. PX4: stream, then switch (OFFBOARD needs a fresh
        stream); ArduPilot: switch to GUIDED first (it is armed in it), then stream. The switch is
        asked before this frame's answer, so in lockstep it lands in a known frame.

        ``mode_known=False`` (just after an episode reset, which leaves the vehicle holding, or
        after a lost link): the mode comes from HEARTBEATs, 1 Hz, and the one saying what the
        vehicle did meanwhile may be lost or late; the last one heard may still say offboard.
        Then ask anyway (asking for the mode the vehicle is in is accepted): otherwise the episode
        hovers in hold."""
        d, link = self.dialect, self.port.link
        if mode_known and d.is_offboard(snap.mode):
            return snap
        if not d.stream_before_offboard:
            when_ready(lambda: link.set_mode(d.offboard_mode), f"enter {d.offboard_mode}", self.cfg.arm_timeout_s)
        if not snap.armed:
            arm_when_ready(link, self.cfg.arm_timeout_s)
        if not d.stream_before_offboard:
            self.port.send(HOLD)
            nxt = self.port.next_snapshot()
            if nxt is None:
                raise LinkError(f"lost the vehicle while entering {d.offboard_mode}")
            return nxt
        for attempt in range(OFFBOARD_ATTEMPTS):
            nxt = self._stream_hold(1 if attempt == 0 else RETRY_STREAM_FRAMES, d.offboard_mode)
            try:
                with self.hold_stream_while_asking():
                    link.set_mode(d.offboard_mode)  # raises CommandRejected with the reason if refused
                return nxt
            except CommandRejected:
                # on a lossy link the one setpoint, or the request (then retried a second later,
                # when the setpoint is stale), was lost: stream again and ask again, as PX4 wants
                if attempt == OFFBOARD_ATTEMPTS - 1:
                    raise
        raise AssertionError("unreachable")

    def hold_stream_while_asking(self) -> contextlib.AbstractContextManager[None]:
        """Real time: the hold setpoint keeps flowing while a mode request waits for its ACK."""
        if self.port.lockstep:
            return contextlib.nullcontext()
        return streaming(self.port.link, HOLD, 1.0 / self.cfg.control_rate_hz)

    def _stream_hold(self, frames: int, mode: str) -> VehicleSnapshot:
        """Zero-velocity setpoints for ``frames`` frames (a retry streams longer); the last snapshot."""
        nxt: VehicleSnapshot | None = None
        for _ in range(frames):
            self.port.send(HOLD)
            nxt = self.port.next_snapshot()
            if nxt is None:
                raise LinkError(f"lost the vehicle while entering {mode}")
        assert nxt is not None
        return nxt

    # ----- by the simulator ------------------------------------------------------------------------
    def _prepare_precland(self, notes: list[str]) -> None:
        """Once a run, before its first arming: what the dialect needs at boot (ArduPilot may
        reboot here). Retried by the next episode if it failed."""
        if self.lander is None or self._precland_prepared:
            return
        if self.lander.prepare(self.dialect):
            notes.append(f"precland: rebooted {self.dialect.name} for its boot-time precision landing parameters")
        self._precland_prepared = True

    def _wait_telemetry_after(self, time_boot_ms: int) -> VehicleSnapshot:
        for _ in range(TELEMETRY_FRAMES):
            snap = self.port.next_snapshot()
            if snap is None:
                raise LinkError("no telemetry after the episode reset")
            if snap.time_boot_ms > time_boot_ms and snap.in_air:
                return snap
            if self.port.lockstep:
                self.port.send(HOLD)
        raise LinkError("the vehicle did not report being in the air after the reset")

    # ----- as on a real vehicle ----------------------------------------------------------------------
    def _fly_to_start(self, seed: int | None, notes: list[str]) -> VehicleSnapshot:
        """Arm, take off, fly to a random start above the pad (its SITL disturbed first, if asked)."""
        cfg, port = self.cfg, self.port
        rng = np.random.default_rng(seed)
        pad = np.asarray(cfg.pad_ned_m, dtype=float)
        start = pad + np.array([*rng.uniform(-cfg.start_xy_range_m, cfg.start_xy_range_m, 2), -cfg.start_height_above_pad_m])
        snap = port.next_snapshot()
        if snap is None:
            raise LinkError("no telemetry: cannot start the episode")
        if not self._asked_truth:
            self._asked_truth = True
            ask_for_truth(port.link, snap.autopilot, self.parts.truth_rate_hz)
        if self.parts.autopilot_sim is not None:
            notes += self.parts.autopilot_sim.prepare_episode(port.link, snap.autopilot, 0 if seed is None else seed)
        if not snap.in_air or not snap.armed:  # disarmed is on the ground, whatever a stale landed state says
            if self.truth_ground is not None:
                self._measure_ground(snap)
            snap = self._take_off()
        if snap is not None:
            self._check_home()
        return self._goto(start, snap)

    def _measure_ground(self, snap: VehicleSnapshot) -> None:
        """The truth's level of the vehicle standing disarmed (companion/control/truth_contact.py),
        from the first snapshot that carries the truth (asked for just before, at the first start)."""
        assert self.truth_ground is not None
        for _ in range(TRUTH_FRAMES):
            self.truth_ground.observe_standing(snap)
            if self.truth_ground.ground_down_m is not None and snap.true_pose is not None:
                return
            nxt = self.port.next_snapshot()
            if nxt is None:
                break
            snap = nxt
        log.warning("no truth from the vehicle standing before its take-off: touchdowns by truth contact use "
                    "the last level measured (%s)", self.truth_ground.ground_down_m)

    def _take_off(self) -> VehicleSnapshot | None:
        """Take off and wait for the climb (30 s of control steps). The last episode leaves the
        vehicle armed on the ground, and its autopilot disarms it a while after the landing (PX4
        ``COM_DISARM_LAND``, 2 s of its time): when that falls on the take-off, the vehicle stands
        disarmed and is taken off once more. The faster a SITL runs, the shorter that while is
        against the companion's wall-clock work between episodes."""
        cfg, port = self.cfg, self.port
        snap: VehicleSnapshot | None = None
        for attempt in range(TAKEOFF_ATTEMPTS):
            take_off(port.link, self.dialect, cfg.takeoff_alt_m, cfg.arm_timeout_s)
            snap = self._climb()
            if snap is None or snap.armed or snap.in_air:
                return snap
            if attempt + 1 < TAKEOFF_ATTEMPTS:
                log.warning("the vehicle disarmed itself as it took off (its disarm after the last landing): "
                            "taking off again")
        return snap

    def _climb(self) -> VehicleSnapshot | None:
        """Snapshots until the vehicle is up (the last one), or it is seen armed and then disarmed."""
        cfg, port = self.cfg, self.port
        snap: VehicleSnapshot | None = None
        seen_armed = False
        for _ in range(int(30 * cfg.control_rate_hz)):
            snap = port.next_snapshot()
            if snap is None:
                continue
            if snap.in_air and port.home.height(snap) > 0.8 * cfg.takeoff_alt_m:
                return snap
            seen_armed = seen_armed or snap.armed
            if seen_armed and not snap.armed:
                return snap
        return snap

    def _check_home(self) -> None:
        home = self.port.home
        if self._warned_home:
            return
        self._warned_home = True
        if home.origin is None:
            log.warning("the vehicle sent no HOME_POSITION and was not seen standing: heights are taken "
                        "from local z = 0, which on PX4 is where the estimator started, not the ground")
        else:
            log.info("home: %s, at %s in the vehicle's frame", home.source, tuple(round(v, 3) for v in home.origin))

    def _goto(self, target: np.ndarray, snap: VehicleSnapshot | None) -> VehicleSnapshot:
        """Fly to ``target`` (relative to home) with position setpoints in the vehicle's frame."""
        port, yaw = self.port, 0.0
        for i in range(int(60 * self.cfg.control_rate_hz)):
            if snap is None:
                raise LinkError("lost the vehicle while flying to the start point")
            north, east, down = port.home.to_vehicle(target.tolist())
            port.link.send_position_ned(north, east, down, yaw, echo_time_boot_ms=port.frame_ms if port.lockstep else None)
            if i % 10 == 2 and not self.dialect.is_offboard(snap.mode):  # again if a failsafe took it
                port.link.set_mode(self.dialect.offboard_mode)
            err = float(np.linalg.norm(np.asarray(port.home.relative(snap)) - target))
            speed = float(np.linalg.norm(snap.velocity_ned_m_s))
            if i > 3 and err < self.cfg.start_tolerance_m and speed < 0.3:
                return snap
            snap = port.next_snapshot()
        raise ColError(f"did not reach the start point {target.round(2).tolist()} within 60 s")
