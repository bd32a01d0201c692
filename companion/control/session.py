"""The episode loop on one vehicle over MAVLink: the session's driver of the episode core.

One control step: read the frame (lockstep: wait for the SITL's frame marker; real time: a
ticker at ``control_rate_hz``; companion/control/link_port.py), judge it by the one rule
(companion/control/outcome.py), build the observation, let the step decide (the person and the
policy, the arbiter, mapper, limiter and touchdown assist; companion/control/step.py), send the
setpoint (echoing the frame in lockstep) or have asking for help hold or land
(companion/control/help_session.py), record the person's sample, then give the learner its turn.
A step whose telemetry is no newer than the last step's (companion/control/freshness.py) holds
instead and records nothing, and a step whose camera frame is missing flies but is not recorded
(companion/control/gaps.py). Episodes start through the simulator's control surface when there
is one, else by flying to the start point (companion/control/episode_start.py); with a precision
lander the autopilot lands instead (companion/control/precland.py). They end on touchdown, at the
geofence or after ``max_steps``, and are scored and recorded by the core
(companion/control/records.py).
"""

from __future__ import annotations

import itertools
import logging
import math
import sys
import time
from collections import deque

from companion.control import outcome as outcome_rule
from companion.control.arbiter import Phase
from companion.control.episode_start import EpisodeStart
from companion.control.freshness import FreshnessGate
from companion.control.gaps import (
    LINK_LOST,
    STALE_TELEMETRY,
    VIDEO_MISSING,
    GapReporter,
)
from companion.control.help_session import HelpSession
from companion.control.link_port import HOLD, LinkPort
from companion.control.pace import pace_note
from companion.control.parts import EpisodeParts
from companion.control.policy_frame import policy_position
from companion.control.precland import fly_precland
from companion.control.records import StepView, episode_record, supervised_steps
from companion.control.sequences import leave_safe
from companion.control.step import StepPipeline
from companion.control.touchdown import Evidence, VehicleTouchdown
from companion.control.truth_contact import TruthGround
from companion.errors import ColError, LinkLost
from companion.link.dialect import Dialect
from companion.link.home import HomeFrame
from companion.msg.command import JoystickCommand
from companion.msg.episode import EpisodeRecord
from companion.msg.snapshot import VehicleSnapshot

log = logging.getLogger(__name__)
STAND_DOWN_FRAMES = 50  # frames (about 5 s) for the vehicle to say it is disarmed after a forced disarm
LATENCIES_KEPT = 10_000  # about 16 min of control steps at 10.5 Hz


class EpisodeRunner:
    """Runs episodes with the given parts; one at a time, on the calling thread."""

    def __init__(self, parts: EpisodeParts) -> None:
        self.p = parts
        self.period_s = 1.0 / parts.cfg.control_rate_hz
        self._tick_start_s: float | None = None
        self.step_latencies_s: deque[float] = deque(maxlen=LATENCIES_KEPT)
        """The latest steps' own compute times (bounded: a long run must not grow without end)."""
        self._evidence: Evidence | None = None
        self.home = HomeFrame()
        """Home for heights and distances (companion/link/home.py), kept over the run."""
        self.touchdown = VehicleTouchdown(parts.landing, self.period_s, -parts.cfg.pad_ned_m[2], self.home,
                                          parts.limiter.max_down_m_s, parts.link)
        """Touchdowns the vehicle's land detector recognises (companion/control/touchdown.py)."""
        self.port = LinkPort(parts.link, parts.lockstep, parts.cfg.control_rate_hz, self.home, parts.dialect,
                             parts.cfg.clock)
        cfg = parts.cfg
        self.truth_ground = TruthGround(cfg.truth_contact_m) if cfg.touchdown_by_truth_contact else None
        """A SITL's truth judging the first ground contact (companion/control/truth_contact.py)."""
        self.starter = EpisodeStart(self.port, parts, lambda: self.dialect, self.truth_ground)
        self.trace: list[tuple[int, float, str]] = []
        """The last episode, step by step: (step, disagreement, who flew: policy, human, hold, land)."""
        self._fresh = FreshnessGate()
        self.gaps = GapReporter(lambda: self.p.control)
        """The current episode's steps that were not true samples, by kind (control/gaps.py)."""
        self.help = (HelpSession(parts.asker, parts.human, self.port, self.period_s, parts.on_ask_event)
                     if parts.asker is not None else None)
        """Asking for help (companion/control/help_session.py); None: the session never asks."""
        self.step = StepPipeline(parts, self.period_s, self.help, self.touchdown, parts.demo_noise)
        """Each step's decision (companion/control/step.py)."""

    @property
    def dialect(self) -> Dialect:
        """How this vehicle's autopilot does offboard, hold, land and take-off (LinkPort.dialect)."""
        return self.port.dialect

    def leave_safe(self) -> str:
        """The configured end-of-run state (land or hold), after a run or a failed episode."""
        return leave_safe(self.p.link, self.dialect, self.p.cfg.end_of_run)

    # ----- the vehicle ------------------------------------------------------------------------
    def _recover_link(self) -> VehicleSnapshot | str:
        """Link lost: nothing streamed (the vehicle's failsafe holds) until it comes back: its
        first snapshot; or why the episode ends instead (LinkPort.wait_for_link)."""
        self.gaps.note(LINK_LOST)
        log.warning("link lost: not streaming setpoints; the vehicle's failsafe holds. Waiting %.0f s",
                    self.p.cfg.link_patience_s)
        control = self.p.control
        return self.port.wait_for_link(self.p.cfg.link_patience_s,
                                       control.end_requested if control is not None else lambda: None)

    # ----- the loop --------------------------------------------------------------------------
    def run(self, episode: int, phase: Phase, seed: int | None) -> EpisodeRecord:
        """Fly one episode; never raises for what happens in flight (it is in the record)."""
        wall0 = time.monotonic()
        self._fresh.reset()  # the first step needs only complete telemetry
        self.gaps.begin()
        self.step.reset(episode)
        self._begin_asking(episode)
        try:
            first, notes = self.starter.start(seed)
        except ColError as exc:  # refused reset, no OFFBOARD, lost vehicle: this episode only
            log.error("episode %d could not start: %s", episode, exc)
            self._leave_safe_after_error()
            return self._record(episode, phase, seed, 0, "error", None, None, 0, wall0, [f"start failed: {exc}"])
        t0_ms = first.time_boot_ms
        self._begin_rendered_world(t0_ms, seed)
        snap: VehicleSnapshot | None = first
        outcome, version, steps = "timeout", None, 0
        try:
            self._evidence = None
            if self.p.lander is not None:
                outcome, steps, snap = fly_precland(
                    self.p.lander, self.port, self.dialect, snap, max_steps=self.p.cfg.max_steps,
                    recover=self._recover_link, stop=lambda step, now: self._stop_reason(step, now, flying=False),
                    asking=self.starter.hold_stream_while_asking())
                notes.append(self.p.lander.counts.note())
            else:
                outcome, version, steps, snap = self._fly(episode, phase, snap, t0_ms)
            if outcome == "touchdown" and self._evidence is not None:
                notes.append(self._evidence.note)
                if self._evidence.stand_down:
                    notes.append(self._stand_down())
        except ColError as exc:
            log.error("episode %d ended by an error: %s", episode, exc)
            outcome = "error"
            notes.append(f"error: {exc}")
            self._leave_safe_after_error()
        if self.help is not None:
            notes.extend(self.help.end(steps))
        notes.extend(self.gaps.notes())
        slow = pace_note(steps, _vehicle_s(snap, t0_ms), self.p.cfg.control_rate_hz)
        if slow is not None and not self.gaps.counter.counts["link"]:  # a lost link's silence is said above
            log.warning("episode %d: %s", episode, slow)
            notes.append(slow)
        if self.p.cfg.policy_pad_ned_m is not None:
            notes.append(f"position seen in the policy's frame: the pad at {list(self.p.cfg.policy_pad_ned_m)} from "
                         f"home there, {list(self.p.cfg.pad_ned_m)} here")
        source_notes = getattr(self.p.observer.camera, "frame_source_notes", None)
        if source_notes is not None:  # the rendered camera: frames from truth or the estimate
            notes.extend(source_notes())
        return self._record(episode, phase, seed, steps, outcome, version, snap, t0_ms, wall0, notes)

    def _stand_down(self) -> str:
        """After a touchdown by the SITL's truth, the vehicle's land detector may never fire (the
        pad it follows drives on): disarmed, forced, so the next start takes off from the ground."""
        try:
            self.p.link.force_disarm()
            for _ in range(STAND_DOWN_FRAMES):  # its HEARTBEAT (1 Hz) says so before the next start looks
                snap = self.port.next_snapshot()
                if snap is not None and not snap.armed:
                    return "disarmed (forced) after the truth's touchdown"
        except ColError as exc:
            log.error("could not disarm after the truth's touchdown: %s", exc)
            return f"not disarmed after the truth's touchdown: {exc}"
        return "disarm forced after the truth's touchdown, but the vehicle still said armed"

    def _leave_safe_after_error(self) -> None:
        """On a vehicle that flies to its starts; a simulator's reset takes the vehicle over anyway
        (and lockstep experiments stay exactly as they were)."""
        if self.p.simulator is not None:
            return
        try:
            self.leave_safe()
        except ColError as exc:  # no heartbeat yet: nothing is flying on our account
            log.error("could not leave the vehicle safe: %s", exc)

    # ----- asking for help -------------------------------------------------------------------
    def _begin_asking(self, episode: int) -> None:
        """New episode: a new trace; the threshold recalibrated on the dataset as it is now."""
        self.trace = []
        if self.help is not None:
            policy = self.p.runner.latest_snapshot if self.p.runner is not None else None
            self.help.begin(episode, policy, self.p.dataset)

    def _fly(self, episode: int, phase: Phase, snap: VehicleSnapshot | None,
             t0_ms: int) -> tuple[str, int | None, int, VehicleSnapshot | None]:
        """The control loop of one episode: (outcome, policy version, steps, last snapshot)."""
        version, steps = None, 0
        for step in itertools.count():
            if snap is None and step < self.p.cfg.max_steps:
                recovered = self._recover_link()
                if isinstance(recovered, str):
                    return recovered, version, steps, None
                snap = recovered
                # the vehicle's failsafe may have left offboard meanwhile, and its 1 Hz HEARTBEAT
                # saying so may not be in yet: ask again whatever the last one said
                snap = self.starter.ensure_offboard(snap, mode_known=False)
            stop = self._stop_reason(step, snap)
            if stop == outcome_rule.FENCE:  # its frame was answered with the hold: a step
                return stop, None, step + 1, snap
            if stop is not None:
                return stop, version, steps, snap
            assert snap is not None  # judged: within the time limit, and recovered above
            steps = step + 1
            try:
                if self._fresh.admit(snap):
                    version = self._control_step(episode, step, phase, snap, t0_ms)
                else:
                    self._hold_on_stale(step)
            except LinkLost as exc:  # the link fell silent between the telemetry and the setpoint
                log.warning("step %d: %s", step, exc)
                snap = None  # the next step recovers the link, as when the telemetry says so
                continue
            if self.p.runner is not None:
                self.p.runner.on_control_step(tick_start_s=self._tick_start_s)
            snap = self.port.next_snapshot()
        raise AssertionError("unreachable")

    def _hold_on_stale(self, step: int) -> None:
        """No newer telemetry since the last step: the zero-velocity hold (through the limiter,
        as a refused input's neutral sticks), nobody asked, nothing recorded."""
        self.gaps.note(STALE_TELEMETRY)
        self.port.send(self.step.limited(JoystickCommand.neutral()))
        self.trace.append((step, math.nan, "hold"))

    def _stop_reason(self, step: int, snap: VehicleSnapshot | None, flying: bool = True) -> str | None:
        """Why the episode ends before this step: the one rule of companion/control/outcome.py
        (time, touchdown, geofence), then an end asked for from outside. ``flying`` False: the
        autopilot's precision landing flies (its own time limit, no companion geofence)."""
        verdict = outcome_rule.judge_vehicle(step, self.p.cfg.max_steps if flying else sys.maxsize, snap,
                                             self.p.fence if flying else None, self.home, self.touchdown.assist,
                                             self.truth_ground)
        if verdict.evidence is not None:
            log.warning("%s", verdict.evidence.message)
            self._evidence = verdict.evidence
        elif verdict.fence_reason is not None:  # hold, and the hold mode, before the episode ends
            log.warning("geofence: %s; holding and ending the episode", verdict.fence_reason)
            self.port.hold_in(self.dialect.hold_mode)
        if verdict.outcome is not None:
            return verdict.outcome
        return self.p.control.end_requested() if self.p.control is not None else None

    def _seen_position(self, snap: VehicleSnapshot) -> tuple[float, float, float]:
        """The position the policy and the person see: from home, in the policy's frame (policy_frame)."""
        cfg = self.p.cfg
        return policy_position(self.home.relative(snap), cfg.pad_ned_m, cfg.policy_pad_ned_m)

    def _control_step(self, episode: int, step: int, phase: Phase, snap: VehicleSnapshot,
                      t0_ms: int) -> int | None:
        """One step that flies (judged by _stop_reason before): its policy version."""
        t_start = self._tick_start_s = time.perf_counter()
        try:
            obs = self.p.observer.observe(snap, self.p.lockstep, self._seen_position(snap))
            vector = obs.to_vector()
        except ValueError as exc:  # non-finite telemetry: hold this step
            log.warning("step %d: unusable telemetry (%s); holding", step, exc)
            self.port.send(HOLD)
            return None
        self.gaps.note(VIDEO_MISSING if obs.frame_missing else None)
        choice = self.step.decide(phase, step, obs, vector, snap)
        lost: LinkLost | None = None
        try:
            if choice.setpoint is None:
                assert self.help is not None  # only asking holds or lands
                self.help.carry_out(choice.action, snap)
            else:
                self.port.send(choice.setpoint)
            self.trace.append((step, choice.score, choice.decision.source))
        except LinkLost as exc:  # silent since this step's telemetry: still a true sample; then recover
            lost = exc
        self.step_latencies_s.append(time.perf_counter() - t_start)
        if self.p.dataset is not None and (sample := choice.sample(episode, step, t0_ms, obs, vector)) is not None:
            self.p.dataset.append(sample)
        if self.p.control is not None:
            self.p.control.on_step(StepView(episode, step, phase, obs, choice.decision, choice.shown, choice.version,
                                            choice.human.override_held, choice.human.hold,
                                            self.p.observer.last_frame_number))
        if lost is not None:
            raise lost
        return choice.version

    def _begin_rendered_world(self, handover_ms: int, seed: int | None) -> None:
        """A rendered camera's pad back at its point at the hand-over, driving from there with the
        episode's drift (companion/vision/rendered.py); our SITL's reset does this itself."""
        begin = getattr(self.p.observer.camera, "begin_episode", None)
        if begin is None or self.p.simulator is not None:
            return
        sim = self.p.autopilot_sim
        begin(handover_ms, sim.pad_drift_for(0 if seed is None else seed) if sim is not None else (0.0, 0.0))

    def _pad_ned_at(self, snap: VehicleSnapshot | None) -> tuple[float, float, float]:
        """Where the pad is as the episode ends: a rendered camera's pad may drive."""
        pad = self.p.cfg.pad_ned_m
        pad_at = getattr(self.p.observer.camera, "pad_ne_at", None)
        if pad_at is None or snap is None or self.p.simulator is not None:
            return pad
        north, east = pad_at(snap.time_boot_ms)
        return (north, east, pad[2])

    def _record(self, episode: int, phase: Phase, seed: int | None, steps: int, outcome: str,
                version: int | None, snap: VehicleSnapshot | None, t0_ms: int, wall0: float,
                notes: list[str]) -> EpisodeRecord:
        simulator = self.p.simulator
        result, said = outcome_rule.score_vehicle(outcome, snap, self.home, self._pad_ned_at(snap),
                                                  judge_radius_m=self.p.judge_radius_m,
                                                  simulator_truth=simulator.truth if simulator is not None else None)
        notes.extend(said)
        return episode_record(
            episode, phase, seed, steps, outcome, result, involvement=self.step.arbiter.summary(),
            control_period_s=self.period_s, policy_version=version,
            dataset_size=len(self.p.dataset) if self.p.dataset is not None else 0,
            sim_time_s=_vehicle_s(snap, t0_ms),
            wall_time_s=time.monotonic() - wall0, notes=notes,
            ask=self.help.summary if self.help is not None else None,
            supervised_steps=supervised_steps(
                phase, steps, self.help.supervised_steps(phase, steps) if self.help is not None else None),
            ask_threshold=self.p.asker.threshold if self.p.asker is not None else None)


def _vehicle_s(last: VehicleSnapshot | None, t0_ms: int) -> float:
    """Seconds of the vehicle's time from the episode's first snapshot to its ``last`` (0 without one)."""
    return ((last.time_boot_ms if last else t0_ms) - t0_ms) / 1000.0
