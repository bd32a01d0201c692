"""The precision-landing pilot: what it asks of each autopilot, and the LANDING_TARGET it streams,
in memory and over sockets against the fake vehicle."""

from __future__ import annotations

import contextlib
import dataclasses
import math
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from colcommon.frames import Frame
from companion.commands import CommandMapper
from companion.config import CompanionConfig, LinkConfig
from companion.control.arbiter import Phase
from companion.control.parts import EpisodeParts
from companion.control.precland import PrecisionLander, fly_precland
from companion.control.safety import Geofence, SetpointLimiter
from companion.control.session import EpisodeRunner
from companion.errors import CommandRejected, LinkTimeout
from companion.inputs.base import HumanCommand, HumanInput
from companion.link.dialect import ARDUPILOT, PX4
from companion.link.landing_target import (
    MAV_FRAME_BODY_FRD,
    MAV_FRAME_LOCAL_NED,
    LandingTarget,
    landing_target,
)
from companion.link.mavlink_link import MavlinkLink
from companion.link.sim_params import PARAM_BUDGET_S
from companion.msg.observation import Observation
from companion.msg.setpoint import VelocitySetpoint
from companion.msg.snapshot import VehicleSnapshot
from companion.testing.fake_vehicle import FakeVehicle
from companion.vision.aruco import ArucoPadDetector
from companion.vision.observer import Observer
from companion.vision.perception import PadDetector
from companion.vision.rendered import RenderedCamera
from sitl.camera import CameraRenderer, camera_matrix
from sitl.config import CameraConfig, WorldConfig
from sitl.world import World

MARKED = CameraConfig(pad_marker="aruco")
K = camera_matrix(MARKED)
CAMERA_RATE_HZ = 12.0
CONFIGS = Path(__file__).resolve().parents[2] / "configs"


def detector() -> ArucoPadDetector:
    return ArucoPadDetector(K, (MARKED.width_px, MARKED.height_px))


class RecordingLink:
    """The calls a lander makes: parameters (echoed as ``echo`` says), modes, targets."""

    def __init__(self, echo: dict[str, float] | None = None) -> None:
        self.calls: list[tuple[str, Any]] = []
        self.echo = echo
        self.param_waits: list[float | None] = []  # each exchange's timeout_s

    def state(self) -> None:
        """No telemetry of its own: a lander keeps the step's snapshot."""
        return None

    def set_param(self, name: str, value: float, timeout_s: float | None = None) -> float | None:
        self.calls.append(("param", (name, value)))
        self.param_waits.append(timeout_s)
        return value if self.echo is None else self.echo.get(name)

    def set_mode(self, name: str) -> None:
        self.calls.append(("mode", name))

    def send_landing_target(self, target: LandingTarget) -> None:
        self.calls.append(("target", target))


class OneFrameCamera:
    """Hands out one frame for every stamp asked."""

    def __init__(self, image: np.ndarray) -> None:
        self.image = image

    def frame_at(self, time_boot_ms: int, timeout_s: float) -> Frame:
        return Frame(1, time_boot_ms, self.image)


def snapshot(attitude: tuple[float, float, float] = (0.0, 0.0, 0.0), position=(0.0, 0.0, -4.0)):  # type: ignore[no-untyped-def]
    from companion.msg.snapshot import VehicleSnapshot

    return VehicleSnapshot(0.0, 5000, 5000, 1, "PX4", True, "AUTO.PRECLAND", "IN_AIR", position,
                           (0.0, 0.0, 0.0), attitude, (0.0, 0.0, 0.0), 0.0, True, True)


def rendered(height_above_roof_m: float, marker: CameraConfig = MARKED) -> np.ndarray:
    world = World(WorldConfig())
    return CameraRenderer(marker, world).render(world.pad_ned(0.0) + np.array([0.0, 0.0, -height_above_roof_m]),
                                                (0.0, 0.0, 0.0), 0.0)


def test_px4_is_asked_for_auto_precland_and_nothing_else() -> None:
    link = RecordingLink()
    PrecisionLander(link, None, detector()).engage(PX4)  # type: ignore[arg-type]
    assert link.calls == [("mode", "AUTO.PRECLAND")]


def test_ardupilot_gets_its_plnd_parameters_then_land() -> None:
    link = RecordingLink()
    PrecisionLander(link, None, detector()).engage(ARDUPILOT)  # type: ignore[arg-type]
    assert link.calls == [("param", ("PLND_ENABLED", 1.0)), ("param", ("PLND_TYPE", 1.0)), ("mode", "LAND")]
    assert link.param_waits == [PARAM_BUDGET_S] * 2  # as long as an episode's simulator parameters


@pytest.mark.parametrize("echo", [{}, {"PLND_ENABLED": 0.0}])
def test_a_parameter_the_vehicle_does_not_confirm_stops_before_the_mode(echo: dict[str, float]) -> None:
    link = RecordingLink(echo)
    with pytest.raises(CommandRejected, match="PLND_ENABLED"):
        PrecisionLander(link, None, detector()).engage(ARDUPILOT)  # type: ignore[arg-type]
    assert all(kind != "mode" for kind, _ in link.calls)


class FakeClock:
    """Time that passes only when the lander sleeps."""

    def __init__(self) -> None:
        self.now_s = 0.0

    def __call__(self) -> float:
        return self.now_s

    def sleep(self, seconds: float) -> None:
        self.now_s += seconds


class BootingLink(RecordingLink):
    """A vehicle whose parameters read back as ``params``; asked to reboot, its HEARTBEAT stops
    for ``silent_s`` (None: it never stops; ``back`` False: it never returns)."""

    def __init__(self, params: dict[str, float], armed: bool = False, silent_s: float | None = 12.0,
                 back: bool = True) -> None:
        super().__init__()
        self.params, self.armed = dict(params), armed
        self.silent_s, self.back = silent_s, back
        self.clock = FakeClock()
        self._rebooted_s: float | None = None

    def read_param(self, name: str, timeout_s: float | None = None) -> float | None:
        self.calls.append(("read", name))
        self.param_waits.append(timeout_s)
        return self.params.get(name)

    def set_param(self, name: str, value: float, timeout_s: float | None = None) -> float | None:
        self.params[name] = value
        return super().set_param(name, value, timeout_s)

    def _heartbeat_s(self) -> float:
        """1 Hz HEARTBEATs, none from the reboot for ``silent_s``."""
        now, start = self.clock.now_s, self._rebooted_s
        if start is None or self.silent_s is None or now < start:
            return math.floor(now)
        if now < start + self.silent_s or not self.back:
            return start
        return math.floor(now)

    def state(self):  # type: ignore[no-untyped-def]
        from dataclasses import replace

        return replace(snapshot(), armed=self.armed, autopilot="ARDUPILOTMEGA", mode="STABILIZE",
                       heartbeat_s=self._heartbeat_s())

    def link_alive(self) -> bool:
        return self.clock.now_s - self._heartbeat_s() < 1.5

    def reboot(self) -> None:
        assert not self.armed, "a reboot asked while armed"
        self.calls.append(("reboot", None))
        self._rebooted_s = self.clock.now_s

    def request_rates(self, rates_hz: dict[str, float] | None = None) -> dict[str, str]:
        self.calls.append(("rates", None))
        return {}


def booting_lander(link: BootingLink) -> PrecisionLander:
    return PrecisionLander(link, None, detector(), clock=link.clock, sleep=link.clock.sleep)  # type: ignore[arg-type]


def test_ardupilot_plnd_off_is_set_then_rebooted_while_disarmed_then_streams_asked_again() -> None:
    link = BootingLink({"PLND_ENABLED": 0.0, "PLND_TYPE": 0.0})
    assert booting_lander(link).prepare(ARDUPILOT) is True
    assert link.calls == [("read", "PLND_ENABLED"), ("read", "PLND_TYPE"), ("param", ("PLND_ENABLED", 1.0)),
                          ("param", ("PLND_TYPE", 1.0)), ("reboot", None), ("rates", None)]
    assert link.param_waits == [PARAM_BUDGET_S] * 4  # an unanswered read would reboot it for nothing


def test_ardupilot_plnd_already_on_is_not_rebooted() -> None:
    link = BootingLink({"PLND_ENABLED": 1.0, "PLND_TYPE": 1.0})
    assert booting_lander(link).prepare(ARDUPILOT) is False
    assert link.calls == [("read", "PLND_ENABLED"), ("read", "PLND_TYPE")]


def test_px4_needs_no_reboot_and_is_not_even_asked() -> None:
    link = BootingLink({})
    assert booting_lander(link).prepare(PX4) is False
    assert link.calls == []


def test_an_armed_vehicle_is_never_rebooted() -> None:
    link = BootingLink({"PLND_ENABLED": 1.0, "PLND_TYPE": 0.0}, armed=True)
    with pytest.raises(CommandRejected, match="disarm"):
        booting_lander(link).prepare(ARDUPILOT)
    assert all(kind in ("read",) for kind, _ in link.calls), link.calls


def test_a_reboot_that_never_goes_silent_says_so() -> None:
    link = BootingLink({"PLND_TYPE": 0.0}, silent_s=None)
    with pytest.raises(LinkTimeout, match="kept coming"):
        booting_lander(link).prepare(ARDUPILOT)


def test_a_heartbeat_that_does_not_come_back_says_so() -> None:
    link = BootingLink({"PLND_TYPE": 0.0}, back=False)
    with pytest.raises(LinkTimeout, match="did not come back"):
        booting_lander(link).prepare(ARDUPILOT)
    assert ("rates", None) not in link.calls


@pytest.mark.parametrize(("current", "needed"), [({"PLND_ENABLED": 1.0, "PLND_TYPE": 1.0}, False),
                                                  ({"PLND_ENABLED": 1.0, "PLND_TYPE": 2.0}, True),
                                                  ({"PLND_ENABLED": 1.0, "PLND_TYPE": None}, True)])
def test_the_dialect_decides_the_reboot(current: dict[str, float | None], needed: bool) -> None:
    assert ARDUPILOT.precland_reboot_needed(current) is needed
    assert PX4.precland_reboot_needed(current) is False


@pytest.mark.parametrize(("dialect", "frame"), [(PX4, MAV_FRAME_LOCAL_NED), (ARDUPILOT, MAV_FRAME_BODY_FRD)])
def test_a_seen_pad_sends_exactly_the_detections_landing_target(dialect, frame: int) -> None:  # type: ignore[no-untyped-def]
    image = rendered(2.5)
    link = RecordingLink()
    lander = PrecisionLander(link, OneFrameCamera(image), detector())  # type: ignore[arg-type]
    snap = snapshot((0.02, -0.01, 0.3), (1.0, 2.0, -4.0))
    sent = lander.feed(snap, True, dialect)
    pose = detector().detect(image)
    assert pose is not None
    expected = landing_target(pose, K, 5000, frame, snap.attitude_rad, snap.position_ned_m)
    assert link.calls == [("target", expected)]
    assert sent == expected
    assert (lander.counts.frames, lander.counts.detections, lander.counts.sent) == (1, 1, 1)


def test_an_unseen_pad_sends_nothing() -> None:
    """Not position_valid 0: both autopilots would read its zero angles as a target dead below."""
    link = RecordingLink()
    lander = PrecisionLander(link, OneFrameCamera(rendered(2.5, CameraConfig())), detector())  # type: ignore[arg-type]
    assert lander.feed(snapshot(), True, PX4) is None
    assert link.calls == []
    assert (lander.counts.frames, lander.counts.sent) == (1, 0)


def test_non_finite_telemetry_sends_nothing() -> None:
    link = RecordingLink()
    lander = PrecisionLander(link, OneFrameCamera(rendered(2.5)), detector())  # type: ignore[arg-type]
    assert lander.feed(snapshot((0.0, math.nan, 0.0)), True, PX4) is None
    assert link.calls == []
    assert lander.counts.refused == 1


class Nobody(HumanInput):
    def read(self, obs: Observation) -> HumanCommand:
        return HumanCommand.neutral()


class PlacingSimulator:
    """A control surface for the fake vehicle: an episode starts 3 m above the pad."""

    def __init__(self, fake: FakeVehicle, link: MavlinkLink) -> None:
        self.fake, self.link = fake, link

    def reset(self, seed: int | None = None) -> dict:
        self.fake.place(0.0, 0.0, -3.0)
        snap = self.link.state()
        return {"time_boot_ms": snap.time_boot_ms if snap else 0}

    def truth(self) -> dict:
        return {"touchdown": None}

    def close(self) -> None: ...


@pytest.mark.realtime
def test_over_sockets_landing_target_arrives_at_the_camera_rate_with_the_detectors_values() -> None:
    """PX4-like fake: AUTO.PRECLAND asked by DO_SET_MODE (4, 9), then one LANDING_TARGET per
    camera frame (rendered from the fake's telemetry) until the fake reports touchdown."""
    cfg = CompanionConfig()
    with FakeVehicle(stream_rate_hz=20.0) as fake, MavlinkLink(LinkConfig(connection=fake.connection_string)) as link:
        link.connect(timeout_s=10.0)
        world = WorldConfig(vehicle_height_m=0.0)  # the fake's ground is the roof
        camera = RenderedCamera(link.state, MARKED, world, rate_hz=CAMERA_RATE_HZ)
        camera.open()
        try:
            lander = PrecisionLander(link, camera, detector())
            parts = EpisodeParts(
                link=link, observer=Observer(None, PadDetector(), (320, 240)), mapper=CommandMapper(cfg.commands),
                human=Nobody(), fence=Geofence(30.0, -1.0, 25.0), limiter=SetpointLimiter(cfg.commands, cfg.safety),
                cfg=cfg.session.model_copy(update={"max_steps": 150}), lockstep=False,
                simulator=PlacingSimulator(fake, link),  # type: ignore[arg-type]
                lander=lander, landing=None,
            )
            started = time.monotonic()
            record = EpisodeRunner(parts).run(0, Phase.AUTONOMOUS, 0)
            wall_s = time.monotonic() - started
        finally:
            camera.close()
        mode_requests = [m for m in fake.commands(mavlink.MAV_CMD_DO_SET_MODE) if (int(m.param2), int(m.param3)) == (4, 9)]
        wire = fake.messages("LANDING_TARGET")
    assert record.outcome == "touchdown", record
    assert mode_requests, "AUTO.PRECLAND (main 4, sub 9) was not asked for"
    assert len(wire) == lander.counts.sent >= 15
    assert any("LANDING_TARGET" in note for note in record.notes)
    stamps_ms = [m.time_usec / 1000 for m in wire]
    assert stamps_ms == sorted(set(stamps_ms)), "one message per frame, in order"
    rate_hz = (len(wire) - 1) / ((stamps_ms[-1] - stamps_ms[0]) / 1000)
    assert 0.6 * CAMERA_RATE_HZ < rate_hz < 1.25 * CAMERA_RATE_HZ, (rate_hz, wall_s)
    for msg, sent in zip(wire, lander.sent, strict=True):
        assert (msg.frame, msg.type, msg.position_valid, msg.target_num) == (MAV_FRAME_LOCAL_NED, 2, 1, 0)
        for name in ("angle_x", "angle_y", "distance", "size_x", "size_y", "x", "y", "z"):
            assert getattr(msg, name) == pytest.approx(getattr(sent, name), rel=1e-5, abs=1e-5)
        assert msg.time_usec == sent.time_usec
        # the fake hovers level over the pad, which is at its local origin
        assert math.hypot(msg.x, msg.y) < 0.05 and abs(msg.z) < 0.2
        assert abs(msg.angle_x) < 0.05 and abs(msg.angle_y) < 0.05


def test_the_precland_pilot_needs_the_board_on_the_pad(tmp_path) -> None:  # type: ignore[no-untyped-def]
    from companion.app import RunOptions, precland_options
    from companion.errors import ConfigError

    with pytest.raises(ConfigError, match='pad_marker = "aruco"'):
        precland_options(RunOptions(pilot="precland"))
    opts = precland_options(RunOptions(pilot="precland", condition="col", config_path=CONFIGS / "precland.toml"))
    assert (opts.condition, opts.learn, opts.record) == ("eval", False, False)
    assert precland_options(RunOptions(pilot="expert")) == RunOptions(pilot="expert")


def test_a_precland_episode_lasts_max_steps_control_periods_whatever_the_camera_rate() -> None:
    """Real time: steps are camera frames (30 Hz for a rendered camera), so 500 of them were
    16.7 s and real PX4 timed out before its approach was done; the vehicle's clock decides."""
    from companion.control.precland import precland_time_is_up

    limit_ms = 500 / 10.5 * 1000  # 47.6 s
    assert not precland_time_is_up(1400, int(limit_ms) - 1, 500, 10.5, lockstep=False)  # 1,400 frames at 30 Hz
    assert precland_time_is_up(1429, int(limit_ms) + 1, 500, 10.5, lockstep=False)
    assert precland_time_is_up(10_000, 0, 500, 10.5, lockstep=False)  # a clock that stands still is bounded
    assert not precland_time_is_up(499, 10**9, 500, 10.5, lockstep=True)  # lockstep: the count, as before
    assert precland_time_is_up(500, 0, 500, 10.5, lockstep=True)


# ----- the episode the autopilot lands (fly_precland) -------------------------------------------
class FramePort:
    """A port that hands out the frames given (None: the link fell silent) and keeps what it was sent."""

    def __init__(self, frames: list[VehicleSnapshot | None], lockstep: bool = True) -> None:
        self.frames, self.lockstep, self.control_rate_hz = list(frames), lockstep, 10.0
        self.calls: list[str] = []
        self.sent: list[VelocitySetpoint] = []

    def send(self, sp: VelocitySetpoint) -> None:
        self.calls.append("send")
        self.sent.append(sp)

    def next_snapshot(self) -> VehicleSnapshot | None:
        self.calls.append("next")
        return self.frames.pop(0)

    def newest(self) -> VehicleSnapshot | None:
        self.calls.append("newest")
        return self.frames.pop(0)


def frames_from(ms: int, n: int) -> list[VehicleSnapshot | None]:
    return [dataclasses.replace(snapshot(), time_boot_ms=ms + 100 * i) for i in range(n)]


def test_a_landed_precland_episode_answers_each_frame_until_the_stop_rule_ends_it() -> None:
    link, entered = RecordingLink(), []

    @contextlib.contextmanager
    def asking():  # type: ignore[no-untyped-def]
        entered.append(len(link.calls))
        yield
        entered.append(len(link.calls))

    port = FramePort(frames_from(1100, 5))
    judged: list[int] = []

    def stop(step: int, snap: VehicleSnapshot) -> str | None:
        judged.append(snap.time_boot_ms)
        return "touchdown" if step == 3 else None

    first = dataclasses.replace(snapshot(), time_boot_ms=1000)
    outcome, steps, last = fly_precland(PrecisionLander(link, None, detector()), port, PX4, first, max_steps=50,  # type: ignore[arg-type]
                                        recover=lambda: "link_lost", stop=stop, asking=asking())
    assert (outcome, steps, last and last.time_boot_ms) == ("touchdown", 3, 1300)
    assert link.calls == [("mode", "AUTO.PRECLAND")] and entered == [0, 1]  # asked within the hold stream
    assert judged == [1000, 1100, 1200, 1300]  # every frame judged before it is flown
    assert port.calls == ["send", "next"] * 3 and set(port.sent) == {VelocitySetpoint(0.0, 0.0, 0.0, 0.0)}


def test_a_precland_episode_times_out_and_waits_out_a_lost_link() -> None:
    port = FramePort(frames_from(1100, 20))
    lander = PrecisionLander(RecordingLink(), None, detector())  # type: ignore[arg-type]
    outcome, steps, _ = fly_precland(lander, port, PX4, snapshot(), max_steps=4, recover=lambda: "link_lost",  # type: ignore[arg-type]
                                     stop=lambda step, snap: None)
    assert (outcome, steps) == ("timeout", 4)
    lost = FramePort([*frames_from(1100, 2), None])
    assert fly_precland(lander, lost, PX4, snapshot(), max_steps=10, recover=lambda: "stopped",  # type: ignore[arg-type]
                        stop=lambda step, snap: None) == ("stopped", 3, None)
    back = FramePort([None, *frames_from(1300, 3)])
    outcome, steps, _ = fly_precland(lander, back, PX4, snapshot(), max_steps=3,  # type: ignore[arg-type]
                                     recover=lambda: dataclasses.replace(snapshot(), time_boot_ms=1200),
                                     stop=lambda step, snap: None)
    assert (outcome, steps) == ("timeout", 3)  # the recovered frame is flown on


def test_in_real_time_a_precland_step_takes_the_newest_telemetry_when_a_camera_paces_it() -> None:
    paced = FramePort(frames_from(1100, 3), lockstep=False)
    lander = PrecisionLander(RecordingLink(), OneFrameCamera(np.zeros((240, 320, 3), np.uint8)), detector())  # type: ignore[arg-type]
    fly_precland(lander, paced, PX4, snapshot(), max_steps=10, recover=lambda: "link_lost",  # type: ignore[arg-type]
                 stop=lambda step, snap: "touchdown" if step == 2 else None)
    assert paced.calls == ["newest", "newest"] and lander.counts.frames == 2  # no setpoint: nothing to answer
    unpaced = FramePort(frames_from(1100, 3), lockstep=False)
    fly_precland(PrecisionLander(RecordingLink(), None, detector()), unpaced, PX4, snapshot(), max_steps=10,  # type: ignore[arg-type]
                 recover=lambda: "link_lost", stop=lambda step, snap: "touchdown" if step == 2 else None)
    assert unpaced.calls == ["next", "next"]  # without a camera the control rate paces it


def test_a_real_time_frame_is_placed_from_the_newer_snapshot() -> None:
    from companion.control.precland import fresher

    old = dataclasses.replace(snapshot(position=(0.0, 0.0, -4.0)), time_boot_ms=1_000)
    new = dataclasses.replace(snapshot(position=(0.0, 0.0, -3.7)), time_boot_ms=1_400)  # descended meanwhile
    assert fresher(old, new) is new and fresher(new, old) is new and fresher(old, None) is old
