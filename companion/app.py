"""Wiring: config + options -> link, camera, pilot, learner, dataset -> episodes -> run folder.

Used by the ``col`` commands and the experiment harness. A run folder holds ``human.csv``
(the human dataset), ``checkpoints/episode_NNN.npz`` (one per episode), ``episodes.jsonl``
(one record per episode), ``session.tlog`` (MAVLink telemetry log) and ``summary.json``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import math
import socket
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Literal, Protocol

from colcommon.heap import fix_mmap_threshold, release_free_heap
from colcommon.numeric_env import append_record
from companion import install_hint
from companion.commands import CommandMapper
from companion.config import CompanionConfig
from companion.control.arbiter import Phase
from companion.control.ask import HelpAsker
from companion.control.demo_noise import DemoNoise
from companion.control.parts import EpisodeControl, EpisodeParts
from companion.control.precland import PrecisionLander
from companion.control.safety import Geofence, SetpointLimiter
from companion.control.session import EpisodeRunner
from companion.errors import ColError, ConfigError, SimulatorError
from companion.inputs.base import HumanCommand, HumanInput
from companion.learning.checkpoint import load_checkpoint, save_checkpoint
from companion.learning.col_plus import COL_PLUS, col_plus_config
from companion.learning.dataset import HumanDataset, load_csv
from companion.learning.fit import Fit, fit_of
from companion.learning.learner import Learner
from companion.learning.learner_process import LearnerProcess
from companion.learning.runners import BudgetedLearner, LearnerThread, make_runner
from companion.learning.snapshot import PolicySnapshot
from companion.link import open_link
from companion.link.base import VehicleLink
from companion.link.connection import parse_connection
from companion.link.dialect import Dialect, dialect_for
from companion.link.signing import read_key
from companion.link.sim_params import AutopilotSim, SimEpisode
from companion.msg.episode import EpisodeRecord
from companion.msg.observation import Observation
from companion.run_folder import prepare_run_dir, removed_if_unused
from companion.simulator import SimulatorClient, SitlProcess, start_sitl
from companion.vision.aruco import ArucoPadDetector
from companion.vision.camera import CameraSource, open_camera
from companion.vision.observer import Observer
from companion.vision.perception import PadDetector
from companion.vision.rendered import RENDER_SCHEME, RenderedCamera

if TYPE_CHECKING:
    from companion.pictures.recorder import FlightRecorder
    from sitl.config import CameraConfig

log = logging.getLogger(__name__)
Condition = Literal["demo", "int", "col", "colplus", "ask", "eval"]
PilotKind = Literal["expert", "manual", "gamepad", "none", "precland"]
PRECLAND = "precland"  # not a person: the autopilot's own precision landing (companion/control/precland.py)
CONDITIONS = ("demo", "int", "col", "colplus", "ask", "eval")
PERSON_CONDITIONS = ("demo", "int", "col", "colplus")
"""What a person flies at the console and in a study (asking for help and evaluation aside)."""


def phases_for(condition: str, episodes: int) -> list[Phase]:
    """The paper's schedules: Demo, Int, CoL (first half demonstrations), or evaluation."""
    if condition == "demo":
        return [Phase.DEMONSTRATION] * episodes
    if condition == "int":
        return [Phase.INTERVENTION] * episodes
    if condition in ("col", "colplus", "ask"):  # CoL+: CoL with the supported learner switches; ask: asked for
        half = episodes // 2
        return [Phase.DEMONSTRATION] * half + [Phase.INTERVENTION] * (episodes - half)
    if condition == "eval":
        return [Phase.AUTONOMOUS] * episodes
    raise ConfigError(f"unknown condition {condition!r}; use one of {', '.join(CONDITIONS)}")


class NoHuman(HumanInput):
    """Nobody at the sticks: neutral, never overriding (evaluation runs)."""

    def read(self, obs: Observation) -> HumanCommand:
        return HumanCommand.neutral()


def build_human(kind: str, cfg: CompanionConfig, link: VehicleLink | None = None) -> HumanInput:
    """The person (or their stand-in) behind the override trigger. A ground station's
    MANUAL_CONTROL needs the link: without one here, attach it later (`attach_human`)."""
    if kind == "expert":
        from companion.inputs.expert import InterveningExpert

        return InterveningExpert(cfg.pilot)
    if kind == "manual":
        from companion.inputs.manual_control import ManualControlInput

        source = ManualControlInput(cfg.pilot)
        if link is not None:
            link.on_manual_control(source.feed)
        return source
    if kind == "gamepad":
        from companion.inputs.gamepad import GamepadInput

        return GamepadInput(cfg.pilot)
    if kind in ("none", PRECLAND):
        return NoHuman()
    if kind.startswith("synthetic:"):  # an experiment's participant, e.g. "synthetic:P2" or "synthetic:H07"
        from companion.inputs.operator import operator_named, operator_pilot
        from companion.inputs.synthetic import on_call_pilot, profile_named, synthetic_pilot

        operator = operator_named(kind.partition(":")[2])
        if operator is not None:  # the human operator model's participant (companion/inputs/operator.py)
            if cfg.ask.enabled:
                raise ConfigError("the human operator model's participants (H01, ...) do not answer requests "
                                  "for help yet; use P1-P4 with --condition ask")
            return operator_pilot(operator, cfg.pilot, cfg.session.control_rate_hz, cfg.session.seed)
        profile = profile_named(kind.partition(":")[2])
        if cfg.ask.enabled:  # asked for help: the participant watches only when asked
            steps = round(cfg.ask.synthetic_response_s * cfg.session.control_rate_hz)
            return on_call_pilot(profile, cfg.pilot, cfg.session.seed, steps)
        return synthetic_pilot(profile, cfg.pilot, cfg.session.seed)
    raise ConfigError(f"unknown pilot {kind!r}; use expert, manual, gamepad, none, precland, synthetic:P1..P4 "
                      "or synthetic:H01.. (the human operator model)")


def attach_human(human: HumanInput, link: VehicleLink) -> None:
    """Connect a human input that listens to the vehicle's link (MANUAL_CONTROL) to it."""
    from companion.inputs.manual_control import ManualControlInput

    if isinstance(human, ManualControlInput):
        link.on_manual_control(human.feed)


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@dataclass
class RunOptions:
    """What a person chooses on the command line (the rest comes from the config)."""

    connection: str | None = None
    simulator: str | None = None  # HOST:PORT of an external SITL's control surface
    pilot: str = "expert"
    condition: str = "col"
    episodes: int | None = None
    checkpoint: Path | None = None
    run_dir: Path | None = None
    config_path: Path | None = None
    seed: int | None = None
    lockstep: bool | None = None  # None: lockstep when the SITL is ours and the pilot synthetic
    learn: bool = True
    record: bool = True
    first_episode: int = 0  # continuing a run folder: number episodes on from here
    camera_rate_hz: float | None = None  # our SITL's camera frames per second (None: its config)
    pictures: bool = False  # write flight.png and the last episode's episode_NNN.mp4 into the run folder


@dataclass
class RunResult:
    run_dir: Path
    records: list[EpisodeRecord] = field(default_factory=list)
    final_snapshot: PolicySnapshot | None = None
    dataset_size: int = 0
    latencies_s: list[float] = field(default_factory=list)
    learner_error: str | None = None
    frame_ages_ms: list[int] = field(default_factory=list)
    """Each observation's camera frame age (the telemetry's time minus the frame's stamp)."""

    @property
    def successes(self) -> int:
        return sum(1 for r in self.records if r.success)

    @property
    def judged(self) -> int:
        """Episodes whose success is known (a real vehicle has no ground truth: None)."""
        return sum(1 for r in self.records if r.success is not None)

    def summary(self) -> dict[str, object]:
        n, judged = len(self.records), self.judged
        return {
            "episodes": n,
            "successes": self.successes if judged else None,
            "success_rate": round(self.successes / judged, 4) if judged else None,
            "success_unknown": n - judged,
            "human_samples": sum(r.human_samples for r in self.records),
            "interventions": sum(r.interventions for r in self.records),
            "dataset_size": self.dataset_size,
            "policy_version": None if self.final_snapshot is None else self.final_snapshot.version,
            "run_dir": str(self.run_dir),
            "learner_error": self.learner_error,
            "frame_age_ms": _percentiles(self.frame_ages_ms),
        }


def _percentiles(values: list[int]) -> dict[str, float] | None:
    """p50/p95 of a run's frame ages (None: no frame was used)."""
    if not values:
        return None
    ordered = sorted(values)

    def at(q: float) -> float:  # nearest rank: a frame age that occurred
        return float(ordered[min(len(ordered) - 1, max(0, math.ceil(q * len(ordered)) - 1))])

    return {"p50": at(0.5), "p95": at(0.95), "n": len(values)}


def default_run_dir(cfg: CompanionConfig, label: str) -> Path:
    return Path(cfg.session.output_dir) / f"{time.strftime('%Y%m%d-%H%M%S')}-{label}"


@contextlib.contextmanager
def vehicle_connection(cfg: CompanionConfig, opts: RunOptions, lockstep: bool) -> Iterator[tuple[str, SitlProcess | None]]:
    """The connection string to use, starting our own SITL when none is given."""
    if opts.connection:
        yield opts.connection, None
        return
    from companion.shared_facts import check_shared_facts
    from sitl.config import load_sitl_config

    check_shared_facts(cfg, load_sitl_config(opts.config_path))  # our SITL flies the same file's world
    port = free_udp_port()
    key_file = cfg.link.signing_key_file  # our SITL gets our key: signing required on both sides
    if key_file:
        read_key(key_file)  # a bad key file is reported before any process starts
    extra = ["--signing-key", key_file] if key_file else []
    if opts.camera_rate_hz:
        extra += ["--camera-rate", str(opts.camera_rate_hz)]
    # Our SITL runs at the companion's priority, in both clocks. In lockstep they take turns, so a
    # SITL niced below the companion gains nothing and, on a machine loaded by other work, starves
    # both (at nice 19 beside nice-10 work its frames came seconds late). In real time it is the
    # vehicle, with a wall clock to keep: 10 steps below the companion (as this once was), behind
    # a loaded machine's other work it fell behind, and the console's pilot waited minutes for an
    # episode. Nothing is lost by waiting for it to start: at a load of 25-33 on 2 cores it took
    # over 30 s.
    sitl = start_sitl(port, clock="lockstep" if lockstep else "realtime", config=opts.config_path,
                      seed=opts.seed, extra_args=extra or None, nice=0, timeout_s=120.0)
    try:
        yield f"udpin:127.0.0.1:{port}", sitl
    finally:
        sitl.stop()


def expected_image_size(opts: RunOptions) -> tuple[int, int]:
    """The image size the observer expects before a first frame: our SITL camera's, set once in
    ``[sitl.camera]`` (a camera of another kind reports its own with its first frame)."""
    from companion.shared_facts import image_size_px
    from sitl.config import load_sitl_config

    return image_size_px(load_sitl_config(opts.config_path))


def simulator_client(opts: RunOptions, sitl: SitlProcess | None) -> SimulatorClient | None:
    """The SITL's control surface: ours, the one named by --simulator, or none (real vehicle)."""
    if sitl is not None:
        return SimulatorClient("127.0.0.1", sitl.control_port)
    if opts.simulator:
        host, sep, port = opts.simulator.rpartition(":")
        if not sep or not port.isdigit():
            raise ConfigError(f"--simulator takes HOST:PORT of the SITL's control surface, got {opts.simulator!r}")
        return SimulatorClient(host or "127.0.0.1", int(port))
    return None


def open_run_camera(cfg: CompanionConfig, sitl: SitlProcess | None, link: VehicleLink,
                 camera_component: int = 100, config_path: Path | None = None) -> CameraSource | None:
    """The camera. ``"auto"``: our SITL's stream, or on another vehicle the stream its MAVLink
    camera (component 100, MAV_COMP_ID_CAMERA) advertises in VIDEO_STREAM_INFORMATION.
    ``"render"``: our renderer driven by the vehicle's telemetry (a vehicle without a camera:
    companion/vision/rendered.py), with ``[sitl.camera]`` and ``[sitl.world]`` of ``config_path``.
    ``"none"``: no camera (a test mode: every observation says the pad is not visible)."""
    if cfg.perception.camera.strip().lower() == "none":
        log.warning("camera none: a test mode, the pad is reported as not visible in every observation")
        return None
    if cfg.perception.camera.strip().lower() == RENDER_SCHEME:
        return open_rendered_camera(cfg, link, config_path)
    auto_uri = sitl.ports.get("camera_uri") if sitl is not None else None
    if auto_uri is None and cfg.perception.camera.strip() == "auto":
        try:
            info = link.request_message("VIDEO_STREAM_INFORMATION", camera_component, cfg.perception.open_timeout_s)
        except ColError as exc:
            log.warning("the vehicle's camera did not describe its video stream: %s", exc)
            info = None
        uri = str(info.get("uri") or "").strip("\x00 ") if info is not None else ""
        auto_uri = uri or None
    try:
        return open_camera(cfg.perception.camera, auto_uri=auto_uri, open_timeout_s=cfg.perception.open_timeout_s)
    except ColError as exc:
        if sitl is None or cfg.perception.camera.strip() != "auto":
            raise  # a source the person named must work: flying blind would record a useless dataset
        log.warning("the SITL's camera is unavailable (%s); flying with the pad reported as not visible", exc)
        return None


def open_rendered_camera(cfg: CompanionConfig, link: VehicleLink, config_path: Path | None) -> RenderedCamera:
    """``--camera render``: the pad world of ``config_path`` seen from the vehicle's reported pose."""
    from sitl.config import load_sitl_config

    sitl_cfg = load_sitl_config(config_path)
    pad_n, pad_e, _ = cfg.session.pad_ned_m
    camera = RenderedCamera(link.state, sitl_cfg.camera, sitl_cfg.world, (pad_n, pad_e),
                            rate_hz=cfg.perception.render_rate_hz, vehicle_clock=cfg.session.clock == "vehicle")
    camera.open()
    log.info("camera: rendered from the vehicle's telemetry at %.0f Hz, pad at (%.1f, %.1f) of its local frame "
             "on a ground vehicle %.1f m high", cfg.perception.render_rate_hz, pad_n, pad_e, sitl_cfg.world.vehicle_height_m)
    return camera


def autopilot_sim_for(cfg: CompanionConfig, config_path: Path | None) -> AutopilotSim | None:
    """A real autopilot's SITL disturbed as our SITL would be (companion/link/sim_params.py): the
    episode's wind drawn by our SITL's own rule from ``[sitl.disturbance]`` of ``config_path``, so
    a seed gives the same air on every vehicle. None when nothing is asked."""
    s = cfg.session
    if not s.autopilot_sim_disturbance and s.sih_mass_scale == 1.0 and s.sih_drag_scale == 1.0:
        return None
    from sitl.config import load_sitl_config
    from sitl.disturbance import EpisodeDisturbance

    disturbance = load_sitl_config(config_path).disturbance

    def episode_for(seed: int) -> SimEpisode:
        drawn = EpisodeDisturbance.draw(disturbance, seed)
        return SimEpisode(drawn.wind_ne_m_s, drawn.turbulence_w20_m_s, drawn.vehicle_velocity_ne_m_s)

    start_height_m = s.start_height_above_pad_m - s.pad_ned_m[2]  # above the ground the vehicle took off from
    return AutopilotSim(episode_for, start_height_m, s.sih_mass_scale, s.sih_drag_scale, disturb=s.autopilot_sim_disturbance)


def _autopilot_sim(cfg: CompanionConfig, opts: RunOptions, simulator: SimulatorClient | None, link: VehicleLink,
                   stack: contextlib.ExitStack) -> AutopilotSim | None:
    """The run's :func:`autopilot_sim_for` when no simulator of ours flies it, put back as the run
    ends (after the end of run: ``stack`` calls back last-in first)."""
    sim = autopilot_sim_for(cfg, opts.config_path) if simulator is None else None
    if sim is not None:
        stack.callback(sim.restore, link)
    return sim


@dataclass(frozen=True)
class Vehicle:
    """What a run flies: the link, the SITL's control surface (None on a real vehicle) and the
    camera (None: the pad counts as not visible)."""

    link: VehicleLink
    simulator: SimulatorClient | None
    camera: CameraSource | None
    owned: bool = False  # a SITL started for this run: stopped after it, nothing to leave safe
    sitl_exit_code: Callable[[], int | None] = lambda: None  # our SITL process's, once it has exited


VehicleOpener = Callable[[CompanionConfig, RunOptions, bool, Path], AbstractContextManager[Vehicle]]
"""(config, options, lockstep, run folder) -> a context holding the connected vehicle, closed on exit."""


@contextlib.contextmanager
def open_vehicle(cfg: CompanionConfig, opts: RunOptions, lockstep: bool, run_dir: Path) -> Iterator[Vehicle]:
    """The vehicle over MAVLink: the one ``--connect`` names, or our own SITL started here."""
    with contextlib.ExitStack() as stack:
        connection, sitl = stack.enter_context(vehicle_connection(cfg, opts, lockstep))
        link_cfg = cfg.link.model_copy(update={"connection": connection})
        link = open_link(link_cfg, tlog_path=run_dir / "session.tlog")
        stack.callback(link.close)
        snapshot = link.connect(timeout_s=30.0)
        check_lockstep(dialect_for(snapshot.autopilot), lockstep)
        simulator = simulator_client(opts, sitl)
        if simulator is not None:
            stack.callback(simulator.close)
        camera = open_run_camera(cfg, sitl, link, config_path=opts.config_path)
        if camera is not None:
            stack.callback(camera.close)
        yield Vehicle(link, simulator, camera, owned=sitl is not None,
                      sitl_exit_code=(lambda: sitl.proc.poll()) if sitl is not None else (lambda: None))


class RunControl(EpisodeControl, Protocol):
    """An operator's hand on a whole run (the console): sees what the run built, and is asked
    before each episode (it may block there, e.g. while paused); False ends the run."""

    def started(self, vehicle: Vehicle, learner: Learner, dataset: HumanDataset) -> None: ...

    def before_episode(self, episode: int, phase: Phase) -> bool: ...


def run_episodes(cfg: CompanionConfig, opts: RunOptions,
                 on_episode: Callable[[EpisodeRecord], None] | None = None,
                 vehicle: VehicleOpener = open_vehicle, *, human: HumanInput | None = None,
                 control: RunControl | None = None) -> RunResult:
    """Connect (or start the SITL), then fly ``episodes`` episodes of ``opts.condition``.

    ``vehicle`` opens what the episodes fly (the experiment's evaluation passes an in-process SITL).
    ``human``: the person's input, instead of the one ``opts.pilot`` names (closed at the end).
    ``control``: an operator watching each step, who may pause, end an episode or stop the run.
    """
    fix_mmap_threshold()  # a long run's memory grows with its data only (colcommon/heap.py)
    opts = precland_options(opts)
    episodes = opts.episodes or cfg.session.episodes
    phases = phases_for(opts.condition, episodes)
    cfg = condition_config(cfg, opts.condition)
    lockstep = _lockstep_for(opts)
    run_dir = opts.run_dir or default_run_dir(cfg, opts.condition)
    initial = _checked_start(cfg, opts)
    with contextlib.ExitStack() as stack:
        if human is None:
            human = build_human(opts.pilot, cfg)  # an unknown pilot or a missing gamepad: before any SITL
        stack.callback(human.close)
        stack.enter_context(removed_if_unused(run_dir))  # a run that fails before it flew leaves no folder
        prepare_run_dir(run_dir)  # unwritable: a clear error before any SITL, link or file
        result = RunResult(run_dir)
        recorder = _recorder(opts, control)
        control = control or recorder
        first = opts.first_episode or next_episode(run_dir)
        append_record(run_dir, command=sys.argv, first_episode=first)  # what its numbers were computed with
        if initial is None and opts.learn and first > 0:
            initial = _resume_policy(run_dir, first)
        opened = stack.enter_context(vehicle(cfg, opts, lockstep, run_dir))
        link, simulator, camera = opened.link, opened.simulator, opened.camera
        dataset = HumanDataset(run_dir / "human.csv" if opts.record else None)
        stack.callback(dataset.close)
        learner = Learner(cfg.learner, dataset, initial=initial)
        runner = make_runner(learner) if opts.learn else None
        if runner is not None:
            runner.start()
            stack.callback(runner.stop)
        attach_human(human, link)
        parts = EpisodeParts(
            link=link,
            observer=Observer(camera, PadDetector(cfg.perception), expected_image_size(opts), cfg.perception.frame_timeout_s),
            mapper=CommandMapper(cfg.commands), human=human,
            fence=Geofence.from_config(cfg.safety), limiter=SetpointLimiter(cfg.commands, cfg.safety),
            cfg=cfg.session, lockstep=lockstep, simulator=simulator,
            runner=runner if runner is not None else _Frozen(learner.latest_snapshot), dataset=dataset,
            control=control,
            asker=HelpAsker(cfg.ask, 1.0 / cfg.session.control_rate_hz) if cfg.ask.enabled else None,
            landing=cfg.landing, truth_rate_hz=cfg.perception.render_rate_hz,
            demo_noise=DemoNoise(cfg.learner.demo_noise_std, cfg.learner.seed) if cfg.learner.demo_noise_std > 0 else None,
            judge_radius_m=camera.success_radius_m if isinstance(camera, RenderedCamera) and simulator is None else None,
        )
        parts.lander = _lander_for(opts, link, camera)
        parts.autopilot_sim = _autopilot_sim(cfg, opts, simulator, link, stack)
        if control is not None:
            control.started(opened, learner, dataset)
        episode_runner = EpisodeRunner(parts)
        check_lockstep(episode_runner.dialect, lockstep)
        if not opened.owned:  # after the last episode, an error or Ctrl-C: before the link closes
            stack.callback(_end_of_run, episode_runner)
        seed0 = cfg.session.seed + (first - opts.first_episode) if opts.seed is None else opts.seed
        with (run_dir / "episodes.jsonl").open("a") as log_file:
            for k, phase in enumerate(phases):
                i = first + k
                if control is not None and not control.before_episode(i, phase):
                    break
                record = episode_runner.run(i, phase, seed0 + k)
                record = _finish_episode(record, phase, run_dir, opts, cfg, learner, dataset, runner)
                log_file.write(json.dumps(record.to_json_dict()) + "\n")
                log_file.flush()
                if parts.asker is not None and opts.record:
                    _write_trace(run_dir / "ask_trace.jsonl", record, episode_runner.trace)
                result.records.append(record)
                if on_episode is not None:
                    on_episode(record)
                release_free_heap()  # a long run's resident memory grows with its data only
                _stop_if_sitl_died(opened, i, run_dir)
        if runner is not None:
            runner.stop()
            result.learner_error = None if runner.error is None else repr(runner.error)
        result.final_snapshot = learner.latest_snapshot
        result.dataset_size = len(dataset)
        result.latencies_s = list(episode_runner.step_latencies_s)
        result.frame_ages_ms = list(parts.observer.frame_ages_ms)
    (run_dir / "summary.json").write_text(json.dumps(result.summary(), indent=1) + "\n")
    if recorder is not None:
        write_pictures(recorder, result, cfg, opts.condition)
    return result


def precland_options(opts: RunOptions) -> RunOptions:
    """The precland pilot flies no policy: nothing learned, no dataset or checkpoints, every
    episode autonomous (its records still go to episodes.jsonl). Its board must be on the pad
    before any SITL starts (ConfigError saying how)."""
    if opts.pilot != PRECLAND:
        return opts
    precland_camera(opts.config_path)
    return dataclasses.replace(opts, condition="eval", learn=False, record=False)


def precland_camera(config_path: Path | None) -> CameraConfig:
    """The ``[sitl.camera]`` whose pad carries the ArUco board: the detector's intrinsics."""
    from sitl.config import load_sitl_config

    camera = load_sitl_config(config_path).camera
    if camera.pad_marker == "none":
        raise ConfigError('--pilot precland needs an ArUco board on the pad: set [sitl.camera] pad_marker = "aruco" '
                          '(or "aruco-disc") in the --config file (configs/precland.toml does); the colour pad gives no pose')
    return camera


def _lander_for(opts: RunOptions, link: VehicleLink, camera: CameraSource | None) -> PrecisionLander | None:
    return build_lander(link, camera, opts.config_path) if opts.pilot == PRECLAND else None


def build_lander(link: VehicleLink, camera: CameraSource | None, config_path: Path | None) -> PrecisionLander:
    """The precision lander with the detector for the camera of ``[sitl.camera]`` (our renderer's
    intrinsics: a real camera needs its own calibration)."""
    from sitl.camera import camera_matrix

    camera_cfg = precland_camera(config_path)
    detector = ArucoPadDetector(camera_matrix(camera_cfg), (camera_cfg.width_px, camera_cfg.height_px),
                                board=camera_cfg.pad_marker)
    return PrecisionLander(link, camera, detector)


def _checked_start(cfg: CompanionConfig, opts: RunOptions) -> PolicySnapshot | None:
    """The policy to start from, after refusing what a user can mistype (a missing checkpoint,
    a connection string no link accepts) before any folder is made, SITL started or port opened."""
    initial = load_checkpoint(opts.checkpoint)[0] if opts.checkpoint else None
    if opts.connection is not None:
        parse_connection(opts.connection, cfg.link.baud)
    return initial


def _finish_episode(record: EpisodeRecord, phase: Phase, run_dir: Path, opts: RunOptions, cfg: CompanionConfig,
                    learner: Learner, dataset: HumanDataset, runner: BudgetedLearner | LearnerThread | LearnerProcess | None) -> EpisodeRecord:
    """After an episode: the data on disk, the learner's between-episode updates, the policy's
    fit and its checkpoint (first: a record line always has its checkpoint; eval: none)."""
    dataset.sync()
    if runner is not None:
        runner.between_episodes()
        record = _with_fit(record, fit_of(learner.latest_snapshot, dataset.view()))
    if opts.record:
        i = record.episode
        save_checkpoint(run_dir / "checkpoints" / f"episode_{i:03d}.npz", learner.latest_snapshot,
                        cfg.learner, dataset_size=len(dataset), episode=i, condition=opts.condition,
                        extra={"phase": phase.value, "outcome": record.outcome, "success": record.success})
    return record


def _lockstep_for(opts: RunOptions) -> bool:
    """As asked; else lockstep for a synthetic pilot in our own SITL's PX4 personality."""
    if opts.lockstep is not None:
        return opts.lockstep
    synthetic = opts.pilot in ("expert", "none", PRECLAND) or opts.pilot.startswith("synthetic")
    return synthetic and not opts.connection and _sitl_autopilot(opts.config_path) == "px4"


def _sitl_autopilot(config_path: Path | None) -> str:
    """The personality of the SITL a run would start (ArduPilot's has no lockstep)."""
    from sitl.config import load_sitl_config

    return load_sitl_config(config_path).personality.autopilot


def check_lockstep(dialect: Dialect, lockstep: bool) -> None:
    """Lockstep needs the vehicle's frame marker; ArduPilot has none."""
    if lockstep and dialect.lockstep_marker is None:
        raise ConfigError(
            f"lockstep needs a frame marker (SYSTEM_TIME) that {dialect.name} does not send; "
            "fly it in real time (--realtime); lockstep is our SITL's PX4 personality's"
        )


def _end_of_run(runner: EpisodeRunner) -> None:
    log.warning("end of run: vehicle %s (companion.session.end_of_run = %s)",
                runner.leave_safe(), runner.p.cfg.end_of_run)


def _stop_if_sitl_died(vehicle: Vehicle, episode: int, run_dir: Path) -> None:
    """The SITL this run started is gone (killed, crashed): no later episode can fly, so stop
    now with a clear error instead of recording one failed episode after another."""
    code = vehicle.sitl_exit_code()
    if code is not None:
        how = f"was killed by signal {-code}" if code < 0 else f"exited with code {code}"
        raise SimulatorError(
            f"the SITL started for this run {how} during episode {episode}; the dataset, the records "
            f"and the checkpoints of finished episodes are kept in {run_dir}. Run again with the "
            "same --run-dir to continue"
        )


def _recorder(opts: RunOptions, control: RunControl | None) -> FlightRecorder | None:
    """The watcher behind the pictures, when asked for and no operator holds the run."""
    if not opts.pictures or control is not None:
        return None
    from companion.pictures.recorder import FlightRecorder

    return FlightRecorder()


def write_pictures(recorder: FlightRecorder, result: RunResult, cfg: CompanionConfig, label: str) -> list[Path]:
    """flight.png and the last episode's video; a failure here is logged, never fails the run."""
    from companion.pictures.flight_plot import plot_flight
    from companion.pictures.video import write_episode_video

    written: list[Path] = []
    outcomes = {r.episode: (r.outcome, r.success) for r in result.records}
    pad = cfg.session.pad_ned_m
    try:  # matplotlib, or OpenCV in the lean install
        written.append(plot_flight(recorder.tracks, outcomes, (pad[0], pad[1]), cfg.pilot.pad_radius_m,
                                   result.run_dir / "flight.png", f"{label}: {len(recorder.tracks)} episode{'' if len(recorder.tracks) == 1 else 's'} from above"))
    except Exception as exc:  # pictures are a courtesy: the run's data is already safe
        log.warning("could not write flight.png: %r", exc)
    if not recorder.frames:
        return written
    last = recorder.frames[-1].episode
    try:
        written.append(write_episode_video(recorder.frames, result.run_dir / f"episode_{last:03d}.mp4",
                                           cfg.session.control_rate_hz))
    except ImportError:
        log.warning("no episode_%03d.mp4: the H.264 video needs PyAV, the console extra (%s)", last,
                    install_hint("console"))
    except Exception as exc:
        log.warning("could not write episode_%03d.mp4: %r", last, exc)
    return written


def condition_config(cfg: CompanionConfig, condition: str) -> CompanionConfig:
    """The config a condition flies with: CoL+'s learner switches (companion/learning/col_plus.py),
    asking for help on for ``ask``; the others as given."""
    if condition == COL_PLUS:
        return col_plus_config(cfg)
    return asking_config(cfg, condition)


def asking_config(cfg: CompanionConfig, condition: str) -> CompanionConfig:
    """The config with asking for help on for the ``ask`` condition (which needs an ensemble)."""
    if condition != "ask" or cfg.ask.enabled:
        return cfg
    if cfg.learner.ensemble_members < 2:
        raise ConfigError("the ask condition needs an ensemble to measure disagreement: set "
                          "[companion.learner] ensemble_members to 2 or more (5 is usual)")
    return cfg.model_copy(update={"ask": cfg.ask.model_copy(update={"enabled": True})})


def _write_trace(path: Path, record: EpisodeRecord, trace: list[tuple[int, float, str]]) -> None:
    """One line per episode: the disagreement and who flew at every step, with the threshold."""
    line = {"episode": record.episode, "phase": record.phase, "threshold": record.ask_threshold,
            "step": [t[0] for t in trace],
            "score": [None if not math.isfinite(t[1]) else round(t[1], 8) for t in trace],
            "who": [t[2] for t in trace]}
    with path.open("a") as fh:
        fh.write(json.dumps(line) + "\n")


def _with_fit(record: EpisodeRecord, fit: Fit) -> EpisodeRecord:
    """The episode's record with the policy's fit after it (None for no samples: JSON has no NaN)."""
    def finite(x: float) -> float | None:
        return round(x, 6) if math.isfinite(x) else None

    return dataclasses.replace(record, loss_all=finite(fit.loss_all),
                               loss_intervention=finite(fit.loss_intervention))


def _resume_policy(run_dir: Path, first: int) -> PolicySnapshot | None:
    """Continuing a run folder: go on learning from its newest checkpoint, not from scratch."""
    for episode in range(first - 1, -1, -1):
        path = run_dir / "checkpoints" / f"episode_{episode:03d}.npz"
        if path.is_file():
            log.info("resuming %s: the policy continues from %s", run_dir, path.name)
            return load_checkpoint(path)[0]
    return None


def next_episode(run_dir: Path) -> int:
    """The number after the last episode of ``run_dir`` (0 for a new folder), from its checkpoints,
    its episode records and its dataset (an episode cut short by a killed process has samples but
    no record), so that a resumed run folder keeps what it has and starts from new seeds."""
    numbers = [int(p.stem.removeprefix("episode_")) for p in (run_dir / "checkpoints").glob("episode_*.npz")
               if p.stem.removeprefix("episode_").isdigit()]
    records = run_dir / "episodes.jsonl"
    if records.is_file():
        for line in records.read_text().splitlines():
            try:
                numbers.append(int(json.loads(line)["episode"]))
            except (ValueError, KeyError, TypeError):
                continue  # a torn last line from an interrupted run
    dataset = run_dir / "human.csv"
    if dataset.is_file():
        try:
            episodes = load_csv(dataset).episode
            numbers += [int(episodes.max())] if len(episodes) else []
        except (ColError, OSError):
            pass  # reported when the dataset itself is opened
    return max(numbers, default=-1) + 1


class _Frozen:
    """A runner that never trains: flies one fixed snapshot (evaluation)."""

    def __init__(self, snapshot: PolicySnapshot) -> None:
        self._snapshot = snapshot
        self.error = None

    @property
    def latest_snapshot(self) -> PolicySnapshot:
        return self._snapshot

    def on_control_step(self, tick_start_s: float | None = None) -> PolicySnapshot:
        return self._snapshot
