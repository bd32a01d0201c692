"""The episode loop's logic on an in-memory vehicle: who flies, what is recorded, safety."""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from dataclasses import replace

import numpy as np
import pytest

from companion.commands import CommandMapper
from companion.config import CompanionConfig
from companion.control.arbiter import Phase
from companion.control.parts import EpisodeParts
from companion.control.safety import Geofence, SetpointLimiter
from companion.control.session import EpisodeRunner
from companion.errors import LinkLost
from companion.inputs.base import HumanCommand, HumanInput
from companion.learning.dataset import HumanDataset
from companion.learning.policy import PolicyNet
from companion.link.base import VehicleLink
from companion.msg.command import JoystickCommand
from companion.msg.observation import Observation
from companion.msg.sample import Source
from companion.msg.setpoint import VelocitySetpoint
from companion.msg.snapshot import VehicleSnapshot
from companion.msg.true_pose import TruePose
from companion.vision.observer import Observer
from companion.vision.perception import PadDetector

FRAME_MS = 95


class KinematicLink(VehicleLink):
    """Lockstep frames from a point mass that follows the last body-velocity setpoint."""

    def __init__(self, start_ned: tuple[float, float, float] = (0.0, 0.0, -3.0)) -> None:
        self.pos = np.array(start_ned, dtype=float)
        self.vel = np.zeros(3)
        self.t_ms = 0
        self.mode = "AUTO.LOITER"
        self.armed = True
        self.sent: list[tuple[VelocitySetpoint, int | None]] = []
        self.modes: list[str] = []
        self.silent_frames: set[int] = set()
        self.alive = True
        self.frame = 0

    def _snap(self) -> VehicleSnapshot:
        landed = "ON_GROUND" if self.pos[2] >= 0 else "IN_AIR"
        return VehicleSnapshot(0.0, self.t_ms, self.t_ms, 1, "PX4", self.armed, self.mode, landed,
                               tuple(self.pos), tuple(self.vel), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0.0, True, True,
                               position_time_boot_ms=self.t_ms, attitude_time_boot_ms=self.t_ms)

    def wait_frame(self, after_time_boot_ms: int, timeout_s: float) -> VehicleSnapshot | None:
        self.frame += 1
        if self.frame in self.silent_frames:
            self.alive = False
            return None
        self.alive = True
        self.t_ms += FRAME_MS
        self.pos = self.pos + self.vel * FRAME_MS / 1000
        self.pos[2] = min(self.pos[2], 0.0)
        return self._snap()

    def send_velocity_body(self, sp: VelocitySetpoint, echo_time_boot_ms: int | None = None) -> None:
        self.sent.append((sp, echo_time_boot_ms))
        self.vel = np.array([sp.forward_m_s, sp.right_m_s, sp.down_m_s])

    def set_mode(self, name: str) -> None:
        self.modes.append(name)
        self.mode = name

    def state(self) -> VehicleSnapshot | None:
        return self._snap()

    def link_alive(self) -> bool:
        return self.alive

    def connect(self, timeout_s: float = 10.0) -> VehicleSnapshot:
        return self._snap()

    def close(self) -> None: ...
    def arm(self) -> None:
        self.armed = True

    def disarm(self) -> None:
        self.armed = False

    def takeoff(self, alt_m: float) -> None: ...
    def land(self) -> None: ...
    def send_position_ned(self, *args: float, echo_time_boot_ms: int | None = None) -> None: ...
    def request_rates(self, rates_hz: Mapping[str, float] | None = None) -> dict[str, str]:
        return {}

    def on_manual_control(self, callback) -> None: ...  # type: ignore[no-untyped-def]
    def stats(self):  # type: ignore[no-untyped-def]
        return None

    def request_message(self, *args, **kwargs):  # type: ignore[no-untyped-def]
        return None


class FakeSimulator:
    """The control surface's reset and truth, for the kinematic vehicle."""

    def __init__(self, link: KinematicLink) -> None:
        self.link = link
        self.resets: list[int | None] = []

    def reset(self, seed: int | None = None) -> dict:
        self.resets.append(seed)
        return {"time_boot_ms": self.link.t_ms}

    def truth(self) -> dict:
        return {"touchdown": None}


class ScriptedHuman(HumanInput):
    """Descends; holds the override on the steps listed."""

    def __init__(self, override_steps: set[int]) -> None:
        self.override_steps = override_steps
        self.step = -1

    def reset(self) -> None:
        self.step = -1

    def read(self, obs: Observation) -> HumanCommand:
        self.step += 1
        return HumanCommand(JoystickCommand(0.0, 0.5, 0.0, -1.0), self.step in self.override_steps)


class Runner:
    def __init__(self, snapshot, error=None) -> None:  # type: ignore[no-untyped-def]
        self.latest_snapshot = snapshot
        self.error = error
        self.steps = 0

    def on_control_step(self, tick_start_s=None):  # type: ignore[no-untyped-def]
        self.steps += 1
        return self.latest_snapshot


def make_runner(link: KinematicLink, human: HumanInput, *, runner=None, fence_radius_m: float = 30.0,  # type: ignore[no-untyped-def]
                max_steps: int = 60, lockstep: bool = True,
                session_update: dict | None = None) -> tuple[EpisodeRunner, HumanDataset]:
    cfg = CompanionConfig()
    session = cfg.session.model_copy(update={"max_steps": max_steps, **(session_update or {})})
    dataset = HumanDataset(None)
    parts = EpisodeParts(
        link=link, observer=Observer(None, PadDetector(), (320, 240)), mapper=CommandMapper(cfg.commands), human=human,
        fence=Geofence(fence_radius_m, -1.0, 25.0), limiter=SetpointLimiter(cfg.commands, cfg.safety),
        cfg=session, lockstep=lockstep, simulator=FakeSimulator(link), runner=runner, dataset=dataset,  # type: ignore[arg-type]
    )
    return EpisodeRunner(parts), dataset


def policy_runner() -> Runner:
    return Runner(PolicyNet(15, (8,), init_std=0.1).snapshot())


def test_demonstration_records_every_step_and_ends_on_touchdown() -> None:
    link = KinematicLink((0.0, 0.0, -3.0))
    runner, dataset = make_runner(link, ScriptedHuman(set()), runner=policy_runner())
    record = runner.run(0, Phase.DEMONSTRATION, seed=1)
    assert record.outcome == "touchdown"
    assert record.human_samples == record.steps == len(dataset) > 20
    assert set(dataset.counts) and dataset.counts[Source.DEMONSTRATION] == len(dataset)
    assert link.modes[0] == "OFFBOARD"
    # every setpoint answers the frame it was computed from
    echoes = [e for _, e in link.sent]
    assert all(e is not None for e in echoes) and echoes == sorted(echoes)


def test_intervention_records_only_the_held_steps_and_counts_them() -> None:
    link = KinematicLink((0.0, 0.0, -3.0))
    held = {3, 4, 5, 10, 11}
    runner, dataset = make_runner(link, ScriptedHuman(held), runner=policy_runner(), max_steps=15)
    record = runner.run(2, Phase.INTERVENTION, seed=1)
    assert len(dataset) == len(held) == record.human_samples
    assert dataset.counts[Source.INTERVENTION] == len(held)
    assert record.interventions == 2
    assert record.intervention_durations_s == pytest.approx((3 / 10.5, 2 / 10.5), abs=1e-3)  # steps x control period
    # the person's command went out on exactly the held steps (descent at full stick)
    downs = [sp.down_m_s for sp, _ in link.sent[1:]]  # sent[0] is the OFFBOARD hand-over hold
    assert [i for i, d in enumerate(downs) if d > 0.9] == sorted(held)


def test_autonomous_never_records() -> None:
    link = KinematicLink()
    runner, dataset = make_runner(link, ScriptedHuman(set(range(100))), runner=policy_runner(), max_steps=10)
    record = runner.run(0, Phase.AUTONOMOUS, seed=1)
    assert len(dataset) == 0 and record.human_samples == 0 and record.outcome == "timeout"


def test_fence_breach_holds_and_ends_the_episode() -> None:
    link = KinematicLink((0.0, 0.0, -3.0))
    runner, _ = make_runner(link, ScriptedHuman(set()), fence_radius_m=0.5)
    record = runner.run(0, Phase.DEMONSTRATION, seed=1)
    assert record.outcome == "fence"
    assert link.sent[-1][0] == VelocitySetpoint(0.0, 0.0, 0.0, 0.0)
    assert link.modes[-1] == "AUTO.LOITER"


def test_a_failed_learner_keeps_the_last_good_policy_flying(caplog: pytest.LogCaptureFixture) -> None:
    link = KinematicLink()
    runner, _ = make_runner(link, ScriptedHuman(set()), runner=Runner(policy_runner().latest_snapshot, RuntimeError("boom")), max_steps=5)
    record = runner.run(0, Phase.AUTONOMOUS, seed=1)
    assert record.steps == 5 and record.policy_version is not None
    assert "learner failed" in caplog.text


def test_link_loss_stops_streaming_then_resumes(monkeypatch: pytest.MonkeyPatch) -> None:
    link = KinematicLink((0.0, 0.0, -5.0))
    link.silent_frames = {6}
    runner, _ = make_runner(link, ScriptedHuman(set()), runner=policy_runner(), max_steps=12)
    monkeypatch.setattr("companion.control.session.time.sleep", lambda s: None)
    sent_before = []

    original = runner._recover_link

    def recover():  # type: ignore[no-untyped-def]
        sent_before.append(len(link.sent))
        link.alive = True
        link.mode = "AUTO.LOITER"  # the vehicle's failsafe took over meanwhile
        return original()

    monkeypatch.setattr(runner, "_recover_link", recover)
    record = runner.run(0, Phase.AUTONOMOUS, seed=1)
    assert sent_before, "the loss was noticed"
    assert link.modes.count("OFFBOARD") == 2  # handed over again after the link came back
    assert record.steps == 12 and record.outcome == "timeout"


def test_link_loss_raised_by_the_link_is_recovered_not_fatal(monkeypatch: pytest.MonkeyPatch) -> None:
    """Real links raise LinkLost from wait_frame when the vehicle falls silent (VehicleLink's contract)."""
    link = KinematicLink((0.0, 0.0, -5.0))
    runner, _ = make_runner(link, ScriptedHuman(set()), runner=policy_runner(), max_steps=12)
    monkeypatch.setattr("companion.control.session.time.sleep", lambda s: None)
    original = link.wait_frame

    def lossy_wait_frame(after: int, timeout_s: float):  # type: ignore[no-untyped-def]
        if link.frame == 5:
            link.frame += 1
            raise LinkLost("nothing heard from the vehicle")
        return original(after, timeout_s)

    link.wait_frame = lossy_wait_frame  # type: ignore[method-assign]
    record = runner.run(0, Phase.AUTONOMOUS, seed=1)
    assert record.steps == 12 and record.outcome == "timeout"


def test_non_finite_telemetry_holds_that_step() -> None:
    link = KinematicLink()
    runner, dataset = make_runner(link, ScriptedHuman(set()), runner=policy_runner(), max_steps=4)
    original = link.wait_frame

    def bad_frame(after: int, timeout_s: float):  # type: ignore[no-untyped-def]
        snap = original(after, timeout_s)
        return replace(snap, velocity_ned_m_s=(math.nan, 0.0, 0.0)) if link.frame == 3 else snap

    link.wait_frame = bad_frame  # type: ignore[method-assign]
    runner.run(0, Phase.DEMONSTRATION, seed=1)
    assert VelocitySetpoint(0.0, 0.0, 0.0, 0.0) in [sp for sp, _ in link.sent[1:]]
    assert len(dataset) == 3  # the bad step is not recorded


def test_an_episode_that_cannot_start_is_recorded_as_an_error_and_the_next_one_flies() -> None:
    from companion.errors import SimulatorError

    link = KinematicLink((0.0, 0.0, -3.0))
    runner, _ = make_runner(link, ScriptedHuman(set()), runner=policy_runner(), max_steps=5)
    sim = runner.p.simulator
    real_reset = sim.reset  # type: ignore[union-attr]

    def refuse_once(seed=None):  # type: ignore[no-untyped-def]
        sim.reset = real_reset  # type: ignore[union-attr]
        raise SimulatorError("simulator refused 'reset': busy")

    sim.reset = refuse_once  # type: ignore[union-attr]
    failed = runner.run(0, Phase.AUTONOMOUS, seed=1)
    assert failed.outcome == "error" and failed.steps == 0 and "busy" in failed.notes[0]
    assert failed.success is False
    ok = runner.run(1, Phase.AUTONOMOUS, seed=2)
    assert ok.outcome == "timeout" and ok.steps == 5


def test_a_refused_offboard_after_link_recovery_ends_only_that_episode(monkeypatch: pytest.MonkeyPatch) -> None:
    from companion.errors import CommandRejected

    link = KinematicLink((0.0, 0.0, -5.0))
    link.silent_frames = {4}
    runner, _ = make_runner(link, ScriptedHuman(set()), runner=policy_runner(), max_steps=12)
    monkeypatch.setattr("companion.control.session.time.sleep", lambda s: None)

    def refuse(name: str) -> None:
        if link.modes:  # the first hand-over works, the one after the loss is refused
            raise CommandRejected("set_mode('OFFBOARD')", "DENIED")
        link.modes.append(name)
        link.mode = name

    def recover():  # type: ignore[no-untyped-def]
        link.alive, link.mode = True, "AUTO.LOITER"
        return link._snap()

    link.set_mode = refuse  # type: ignore[method-assign]
    monkeypatch.setattr(runner, "_recover_link", recover)
    record = runner.run(0, Phase.AUTONOMOUS, seed=1)
    assert record.outcome == "error" and "DENIED" in record.notes[-1]


def test_an_offboard_refused_because_its_setpoint_was_lost_is_asked_again_after_a_fresh_one() -> None:
    from companion.errors import CommandRejected

    link = KinematicLink((0.0, 0.0, -3.0))
    runner, _ = make_runner(link, ScriptedHuman(set()), runner=policy_runner(), max_steps=5)
    refusals = [1]
    real_set_mode = link.set_mode

    def lossy(name: str) -> None:  # the first request finds no fresh setpoint, as on a lossy link
        if refusals[0]:
            refusals[0] -= 1
            raise CommandRejected("set_mode('OFFBOARD')", "DENIED")
        real_set_mode(name)

    link.set_mode = lossy  # type: ignore[method-assign]
    sent_before = len(link.sent)
    record = runner.run(0, Phase.DEMONSTRATION, seed=1)
    assert record.outcome != "error" and link.modes[0] == "OFFBOARD"
    from companion.control.episode_start import RETRY_STREAM_FRAMES

    # one setpoint before the first request, a longer stream before the retry
    assert len(link.sent) - sent_before >= 1 + RETRY_STREAM_FRAMES + record.steps


def test_after_a_reset_offboard_is_asked_for_even_if_the_last_heartbeat_said_offboard() -> None:
    """The reset leaves the vehicle holding; its HEARTBEAT saying so was lost (a lossy link), so
    the last one heard still says OFFBOARD from the episode before. The start asks anyway:
    without it the episode hovered in hold until its timeout."""
    link = KinematicLink((0.0, 0.0, -3.0))
    runner, _ = make_runner(link, ScriptedHuman(set()), runner=policy_runner(), max_steps=5)
    runner.run(0, Phase.DEMONSTRATION, seed=1)
    assert link.modes == ["OFFBOARD"] and link.mode == "OFFBOARD"  # stale from here on
    link.pos = np.array([0.0, 0.0, -3.0])
    runner.run(1, Phase.DEMONSTRATION, seed=2)
    assert link.modes == ["OFFBOARD", "OFFBOARD"]


class RealTimeKinematicLink(KinematicLink):
    """Telemetry moves on as it is read (real time has no frames to wait for)."""

    def state(self) -> VehicleSnapshot | None:
        self.t_ms += FRAME_MS
        return self._snap()


@pytest.mark.parametrize("lockstep", [False, True])
def test_the_hold_stream_goes_on_while_offboard_is_asked_for_in_real_time_only(lockstep: bool) -> None:
    """A mode request waits for its COMMAND_ACK (a second and more when the ACK is lost): in
    real time the hold setpoint keeps flowing meanwhile, so PX4 neither drops OFFBOARD nor
    refuses it as stale; in lockstep every setpoint answers a frame, and none is added."""
    link = KinematicLink((0.0, 0.0, -3.0)) if lockstep else RealTimeKinematicLink((0.0, 0.0, -3.0))
    runner, _ = make_runner(link, ScriptedHuman(set()), runner=policy_runner(), max_steps=2, lockstep=lockstep)
    sent_while_waiting: list[int] = []
    real_set_mode = link.set_mode

    def slow_ack(name: str) -> None:
        before = len(link.sent)
        time.sleep(0.5)  # 5 control periods
        sent_while_waiting.append(len(link.sent) - before)
        real_set_mode(name)

    link.set_mode = slow_ack  # type: ignore[method-assign]
    runner.run(0, Phase.DEMONSTRATION, seed=1)
    assert link.modes == ["OFFBOARD"]
    if lockstep:
        assert sent_while_waiting == [0]
    else:
        assert sent_while_waiting[0] >= 3  # zero-velocity holds, before the episode's first command
        assert all(sp.forward_m_s == sp.right_m_s == sp.down_m_s == 0.0 for sp, _ in link.sent[:1 + sent_while_waiting[0]])


class GapWatcher:
    """An operator's view: the gaps as the session reports them, and the steps it saw."""

    def __init__(self) -> None:
        self.gaps: list[str | None] = []
        self.steps: list[int] = []

    def on_step(self, view) -> None:  # type: ignore[no-untyped-def]
        self.steps.append(view.step)

    def on_gap(self, gap) -> None:  # type: ignore[no-untyped-def]
        self.gaps.append(None if gap is None else gap.kind)

    def end_requested(self) -> None:
        return None


@pytest.mark.parametrize("lockstep", [True, False])
def test_steps_on_stale_telemetry_hold_and_record_nothing(lockstep: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    """A frozen vehicle: frames (or ticks) come, but its position and attitude stamps stand still."""
    link = KinematicLink((0.0, 0.0, -5.0))
    frozen = set(range(8, 13))  # the link's frame numbers whose telemetry is the last one's
    original = link.wait_frame
    last: list[VehicleSnapshot] = []

    def freezing_wait_frame(after: int, timeout_s: float):  # type: ignore[no-untyped-def]
        snap = original(after, timeout_s)
        if link.frame in frozen and last:  # the marker moves on, the telemetry does not
            link.pos = np.array(last[-1].position_ned_m)
            return replace(last[-1], frame_time_boot_ms=snap.frame_time_boot_ms, time_boot_ms=snap.time_boot_ms)
        last.append(snap)
        return snap

    link.wait_frame = freezing_wait_frame  # type: ignore[method-assign]
    if not lockstep:  # real time: the ticker reads state(); the same freeze through it
        monkeypatch.setattr("companion.control.link_port.Ticker.wait", lambda self: None)
        link.state = lambda: freezing_wait_frame(0, 0.0)  # type: ignore[method-assign]
    runner, dataset = make_runner(link, ScriptedHuman(set()), runner=policy_runner(), max_steps=20, lockstep=lockstep)
    watcher = GapWatcher()
    runner.p.control = watcher  # type: ignore[assignment]
    recorded: list[int] = []
    append = dataset.append
    dataset.append = lambda sample: (recorded.append(sample.step), append(sample))[1]  # type: ignore[method-assign]
    record = runner.run(0, Phase.DEMONSTRATION, seed=1)
    stale = [step for step, _, who in runner.trace if who == "hold"]
    assert len(stale) == len(frozen), runner.trace
    assert record.steps == 20 and record.human_samples == len(dataset) == len(recorded) == 20 - len(frozen)
    assert not set(recorded) & set(stale)
    assert f"{len(frozen)} steps held on stale telemetry, not recorded" in record.notes
    assert watcher.gaps == ["telemetry", None]  # told when the gap started and when it ended
    assert not set(watcher.steps) & set(stale)  # no step is shown as flown on old telemetry
    # every stale step sent the zero-velocity hold
    by_step = dict(zip(range(len(link.sent) - record.steps, len(link.sent)), range(record.steps)))
    holds = [link.sent[i][0] for i, step in by_step.items() if step in stale]
    assert holds and all(sp == VelocitySetpoint(0.0, 0.0, 0.0, 0.0) for sp in holds)


def test_a_step_without_its_camera_frame_flies_but_is_not_recorded() -> None:
    from colcommon.frames import Frame

    class GappyCamera:
        """A camera whose frames 4-6 never come (a stalled stream)."""

        vehicle_time_stamps = True

        def __init__(self) -> None:
            self.asked = 0

        def frame_at(self, time_boot_ms: int, timeout_s: float) -> Frame | None:
            self.asked += 1
            if 4 <= self.asked <= 6:
                return None
            return Frame(self.asked, time_boot_ms, np.zeros((240, 320, 3), np.uint8))

        def latest(self) -> Frame | None:
            return None

    link = KinematicLink((0.0, 0.0, -5.0))
    runner, dataset = make_runner(link, ScriptedHuman(set()), runner=policy_runner(), max_steps=12)
    runner.p.observer = Observer(GappyCamera(), PadDetector(), (320, 240))  # type: ignore[arg-type]
    watcher = GapWatcher()
    runner.p.control = watcher  # type: ignore[assignment]
    record = runner.run(0, Phase.DEMONSTRATION, seed=1)
    assert record.steps == 12 and record.human_samples == len(dataset) == 9
    assert "3 steps flown without a camera frame, not recorded" in record.notes
    assert watcher.gaps == ["video", None]
    assert len(watcher.steps) == 12  # they flew (and were shown), unrecorded


def test_a_link_lost_between_the_telemetry_and_the_setpoint_is_recovered_not_an_error(monkeypatch: pytest.MonkeyPatch) -> None:
    """The link may be declared lost after a step's telemetry was read and before its setpoint goes
    out (a starved or frozen vehicle): the step's sample is still a true one, then the link-loss
    path runs; the episode does not end in an error."""
    link = KinematicLink((0.0, 0.0, -5.0))
    runner, dataset = make_runner(link, ScriptedHuman(set()), runner=policy_runner(), max_steps=12)
    monkeypatch.setattr("companion.control.session.time.sleep", lambda s: None)
    send = link.send_velocity_body
    sent = [0]

    def silent_once(sp, echo_time_boot_ms=None):  # type: ignore[no-untyped-def]
        sent[0] += 1
        if sent[0] == 6:  # the OFFBOARD hand-over's hold, then steps 0-3, then step 4's setpoint
            raise LinkLost("nothing heard from the vehicle")
        send(sp, echo_time_boot_ms)

    link.send_velocity_body = silent_once  # type: ignore[method-assign]
    recovered = []
    original = runner._recover_link

    def recover():  # type: ignore[no-untyped-def]
        recovered.append(len(link.sent))
        return original()

    monkeypatch.setattr(runner, "_recover_link", recover)
    record = runner.run(0, Phase.DEMONSTRATION, seed=1)
    assert record.outcome != "error" and record.steps == 12, record
    assert recovered, "the link-loss path ran"
    assert record.human_samples == len(dataset)  # the step whose setpoint was lost kept its true sample


def test_after_a_link_loss_offboard_is_asked_again_even_if_the_last_heartbeat_says_offboard(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """While the link was silent the vehicle's failsafe left OFFBOARD for a hold; the HEARTBEAT
    saying so (1 Hz) may come after the link is back: the session must not trust the old one
    (a fresh-clone CI run streamed the person's setpoints into a holding vehicle)."""
    link = KinematicLink((0.0, 0.0, -5.0))
    link.silent_frames = {6}
    runner, _ = make_runner(link, ScriptedHuman(set()), runner=policy_runner(), max_steps=12)
    monkeypatch.setattr("companion.control.session.time.sleep", lambda s: None)
    original = runner._recover_link

    def recover():  # type: ignore[no-untyped-def]
        link.alive = True  # the snapshot still says OFFBOARD: its heartbeat is the old one
        return original()

    monkeypatch.setattr(runner, "_recover_link", recover)
    record = runner.run(0, Phase.AUTONOMOUS, seed=1)
    assert link.modes.count("OFFBOARD") == 2, link.modes
    assert record.steps == 12 and record.outcome == "timeout"


class StopWhileLost(GapWatcher):
    """An operator who presses Stop (or Next) once the link is lost."""

    def __init__(self, link: KinematicLink) -> None:
        super().__init__()
        self.link, self.asked_while_lost = link, 0

    def end_requested(self) -> str | None:  # type: ignore[override]
        if not self.link.alive:
            self.asked_while_lost += 1
            return "stopped"
        return None


def test_the_operator_can_end_an_episode_while_the_link_is_lost(monkeypatch: pytest.MonkeyPatch) -> None:
    """A dead link must not keep a person who pressed Next or Stop waiting for link_patience_s:
    the episode ends at once, by their request, with the steps it had."""
    link = KinematicLink((0.0, 0.0, -5.0))
    link.silent_frames = set(range(6, 1000))  # the vehicle never comes back
    runner, _ = make_runner(link, ScriptedHuman(set()), runner=policy_runner(), max_steps=40)
    operator = StopWhileLost(link)
    runner.p.control = operator
    monkeypatch.setattr("companion.control.session.time.sleep", lambda s: None)
    record = runner.run(0, Phase.AUTONOMOUS, seed=1)
    assert record.outcome == "stopped" and operator.asked_while_lost == 1
    assert record.steps < 10 and "link" in " ".join(record.notes)


class FlyToLink(KinematicLink):
    """A vehicle without a simulator: position setpoints put it there (the flight to the start)."""

    def send_position_ned(self, north: float, east: float, down: float, *args: float,  # type: ignore[override]
                          echo_time_boot_ms: int | None = None) -> None:
        self.pos = np.array([north, east, down], dtype=float)
        self.vel = np.zeros(3)


class DrivingPadCamera:
    """The rendered camera's pad world, as the session sees it: no frames, a pad that drives."""

    def __init__(self, velocity_ne_m_s: tuple[float, float]) -> None:
        self.velocity = velocity_ne_m_s
        self.begun: list[tuple[int, tuple[float, float]]] = []

    def begin_episode(self, time_boot_ms: int, drift_ne_m_s: tuple[float, float] = (0.0, 0.0)) -> None:
        self.begun.append((time_boot_ms, drift_ne_m_s))

    def pad_ne_at(self, time_boot_ms: int) -> tuple[float, float]:
        t0, drift = self.begun[-1]
        dt = (time_boot_ms - t0) / 1000.0
        return ((self.velocity[0] + drift[0]) * dt, (self.velocity[1] + drift[1]) * dt)

    def open(self) -> None: ...
    def latest(self):  # type: ignore[no-untyped-def]
        return None

    def frame_at(self, time_boot_ms: int, timeout_s: float):  # type: ignore[no-untyped-def]
        return None

    def close(self) -> None: ...


class DisturbedSim:
    """The autopilot's SITL disturbance, as the episode start and the session ask it."""

    def __init__(self) -> None:
        self.prepared: list[int] = []

    def prepare_episode(self, link: VehicleLink, autopilot: str, seed: int) -> list[str]:
        self.prepared.append(seed)
        return [f"sim: episode {seed}"]

    def pad_drift_for(self, seed: int) -> tuple[float, float]:
        return (0.0, 0.5)


def test_without_a_simulator_the_rendered_pad_drives_from_the_hand_over_and_the_touchdown_is_scored_where_it_is() -> None:
    link = FlyToLink((0.0, 0.0, -3.0))
    camera = DrivingPadCamera((1.0, 0.0))
    runner, _ = make_runner(link, ScriptedHuman(set()), runner=policy_runner(), max_steps=300)
    runner.p.simulator = None
    runner.p.observer = Observer(camera, PadDetector(), (320, 240))  # type: ignore[arg-type]
    runner.p.autopilot_sim = DisturbedSim()  # type: ignore[assignment]
    runner.p.judge_radius_m = 0.5
    record = runner.run(0, Phase.DEMONSTRATION, seed=7)
    assert record.outcome == "touchdown", record.notes
    assert "sim: episode 7" in record.notes and "started by flying to the start point" in record.notes
    assert len(camera.begun) == 1 and camera.begun[0][1] == (0.0, 0.5)  # the hand-over, with the episode's drift
    pad_n, pad_e = camera.pad_ne_at(link.t_ms)  # where the pad drove to by the touchdown
    assert (pad_n, pad_e) != (0.0, 0.0)
    landed = math.hypot(link.pos[0] - pad_n, link.pos[1] - pad_e)
    assert record.touchdown_distance_m == pytest.approx(landed, abs=0.02)
    assert record.touchdown_distance_m != pytest.approx(math.hypot(link.pos[0], link.pos[1]), abs=0.02)


class SeeingHuman(ScriptedHuman):
    """Demonstrates a descent and remembers the positions it was shown."""

    def __init__(self) -> None:
        super().__init__(set())
        self.seen: list[tuple[float, float, float]] = []

    def read(self, obs: Observation) -> HumanCommand:
        self.seen.append(obs.position_ned_m)
        return super().read(obs)


@pytest.mark.parametrize("policy_pad", [None, (0.0, 0.0, -1.5)])
def test_the_policys_frame_moves_what_is_seen_and_recorded_not_what_is_judged(policy_pad) -> None:  # type: ignore[no-untyped-def]
    """A pad on the ground here, on a 1.5 m roof where the policy learned: the person and the
    dataset see every position 1.5 m higher; the touchdown is still judged from home."""
    link = KinematicLink((0.0, 0.0, -3.0))
    human = SeeingHuman()
    runner, dataset = make_runner(link, human, runner=policy_runner(),
                                  session_update={"pad_ned_m": (0.0, 0.0, 0.0), "policy_pad_ned_m": policy_pad})
    record = runner.run(0, Phase.DEMONSTRATION, seed=1)
    assert record.outcome == "touchdown" and len(dataset) == record.steps > 20
    shift = 0.0 if policy_pad is None else -1.5
    assert human.seen[0][2] == pytest.approx(-3.0 + shift, abs=0.05)
    assert human.seen[-1][2] == pytest.approx(shift, abs=0.1)  # on the ground: where the roof was in training
    downs = dataset.view().obs[:, 2] * 10.0  # down_m / 10 m in the vector
    assert downs[0] == pytest.approx(-3.0 + shift, abs=0.05)
    assert (policy_pad is None) == (not any("policy's frame" in n for n in record.notes))


class TruthLink(FlyToLink):
    """A SITL's vehicle that sends its truth (0.44 m off the local origin on the ground: PX4
    SIH's is off by another amount each boot) and whose land detector never fires once armed: on the ground it says LANDING, as
    real ArduCopter did chasing a rendered pad that drove on."""

    GROUND_DOWN_M = 0.44

    def __init__(self) -> None:
        super().__init__((0.0, 0.0, 0.0))
        self.armed = False
        self.forced: list[int] = []

    def _snap(self) -> VehicleSnapshot:
        snap = super()._snap()
        on_ground = self.pos[2] >= 0
        landed = "ON_GROUND" if on_ground and not self.armed else "LANDING" if on_ground else "IN_AIR"
        truth = TruePose(float(self.pos[0]), float(self.pos[1]), float(self.pos[2]) + self.GROUND_DOWN_M,
                         (0.0, 0.0, 0.0), self.t_ms, "HIL_STATE_QUATERNION", 1.0)
        return replace(snap, landed_state=landed, true_pose=truth)

    def takeoff(self, alt_m: float) -> None:
        self.pos = np.array([self.pos[0], self.pos[1], -alt_m])

    def force_disarm(self) -> None:
        self.forced.append(self.t_ms)
        self.armed = False


@pytest.mark.parametrize("asked", [True, False])
def test_the_truths_first_ground_contact_ends_the_episode_and_the_vehicle_is_disarmed_for_the_next(asked: bool) -> None:
    link = TruthLink()
    runner, _ = make_runner(link, ScriptedHuman(set()), runner=policy_runner(), max_steps=300,
                            session_update={"touchdown_by_truth_contact": asked})
    runner.p.simulator = None
    runner.p.observer = Observer(DrivingPadCamera((0.5, 0.0)), PadDetector(), (320, 240))  # type: ignore[arg-type]
    record = runner.run(0, Phase.DEMONSTRATION, seed=7)
    if not asked:  # the vehicle's own word only: it never says ON_GROUND, so the time runs out
        assert record.outcome == "timeout" and not link.forced
        return
    assert record.outcome == "touchdown", record.notes
    assert "touchdown judged by the SITL's truth: first ground contact (the rendered pad is no surface)" in record.notes
    assert "disarmed (forced) after the truth's touchdown" in record.notes
    assert len(link.forced) == 1 and not link.armed
    assert runner.truth_ground is not None and runner.truth_ground.ground_down_m == pytest.approx(TruthLink.GROUND_DOWN_M)
    second = runner.run(1, Phase.DEMONSTRATION, seed=8)  # from the ground again: taken off, flown, ended alike
    assert second.outcome == "touchdown" and len(link.forced) == 2, second.notes


class RunningAheadLink(KinematicLink):
    """A vehicle whose clock runs twice as far as the companion steps (a SITL faster than the
    machine flies it): two frame periods of its time pass between the companion's steps."""

    def wait_frame(self, after_time_boot_ms: int, timeout_s: float) -> VehicleSnapshot | None:
        self.t_ms += FRAME_MS
        return super().wait_frame(after_time_boot_ms, timeout_s)


def test_an_episode_that_fell_behind_the_vehicles_clock_says_so_and_a_kept_one_does_not() -> None:
    behind, _ = make_runner(RunningAheadLink(), ScriptedHuman(set()), runner=policy_runner(), max_steps=40)
    record = behind.run(0, Phase.AUTONOMOUS, seed=1)
    assert record.outcome == "timeout"
    assert any(n.startswith("control kept 5.") and "fell behind the vehicle" in n for n in record.notes), record.notes
    kept, _ = make_runner(KinematicLink(), ScriptedHuman(set()), runner=policy_runner(), max_steps=40)
    assert not any("fell behind" in n for n in kept.run(0, Phase.AUTONOMOUS, seed=1).notes)
