"""The console's session: one run of episodes at a time, on its own thread, driven by the page.

It is the run's :class:`~companion.app.RunControl`: it sees each control step (for the HUD, the
map and the per-episode table), pauses between episodes, ends an episode or the run when the
page asks, and hands the page's sticks to the run as its human input (:class:`BrowserInput`).
What it tells the page goes through ``publish`` (JSON-able dicts) and ``publish_frame``
(camera frames), both callable from any thread.

Between episodes a ready gate waits for the pilot ("go"), unless the run is in auto mode. The
history (the table and plot) is the run folder's ``episodes.jsonl`` with the console's own notes
beside it in ``console.jsonl`` (touchdown point, no stick input), read again on restart. The
pilot may discard the last episode from training (:meth:`HumanDataset.discard_episode`: an
audit line, nothing deleted).
"""

from __future__ import annotations

import json
import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from colcommon.frames import Frame
from companion.app import (
    PERSON_CONDITIONS,
    RunOptions,
    RunResult,
    Vehicle,
    run_episodes,
    write_pictures,
)
from companion.config import CompanionConfig
from companion.console.frames import FramePump
from companion.console.study import ConsoleStudy
from companion.control.arbiter import Phase
from companion.control.gaps import Gap
from companion.control.records import StepView
from companion.errors import ColError, ConfigError
from companion.experiment.study import Block
from companion.inputs.browser import BrowserInput
from companion.learning.dataset import HumanDataset
from companion.learning.learner import Learner
from companion.msg.episode import EpisodeRecord
from companion.pictures.recorder import FlightRecorder

log = logging.getLogger(__name__)
Publish = Callable[[dict[str, Any]], None]
PublishFrame = Callable[[bytes], None]
STOPPED = "stopped"  # the outcome of an episode the operator ended
NOTES_FILE = "console.jsonl"  # the console's notes per episode, beside episodes.jsonl
RUNNING_STATES = ("starting", "running", "ready", "paused", "stopping")


@dataclass(frozen=True)
class ConsoleOptions:
    """Where the console's runs fly and write (from the command line)."""

    run_dir: Path
    connection: str | None = None
    simulator: str | None = None
    config_path: Path | None = None
    camera_rate_hz: float = 35.0
    seed: int | None = None
    learn: bool = True
    pictures: bool = True  # each run writes flight_FIRST-LAST.png and its last episode's video
    rtp: str = ""  # HOST:PORT: also send the camera as H.264 over RTP (a ground station)


@dataclass
class _RunState:
    """What the page shows about the current (or last) run."""

    state: str = "idle"  # idle | starting | running | paused | stopping | finished | failed
    condition: str | None = None
    episodes: int = 0
    error: str | None = None
    episode: int | None = None
    phase: str | None = None
    track_ne: list[list[Any]] = field(default_factory=list)  # [north, east, who] per step
    last_step: dict[str, Any] | None = None
    auto: bool = False  # episodes follow one another without the pilot's "go"
    ready_for: int | None = None  # the episode waiting for the pilot's "go"
    stage: str | None = None  # what a starting run is doing (the first step takes seconds)
    started_wall_s: float | None = None
    summary: str | None = None  # the message at the end of the run
    gap: dict[str, Any] | None = None  # why steps are not recorded now (control/gaps.py), if they are not


@dataclass
class _EpisodeWatch:
    """What the console notices during one episode (for the HUD and its notes)."""

    recorded: int = 0
    moved: int = 0  # recorded steps with a stick outside the deadband
    pad_k_px_m: float | None = None  # radius_px x height above the pad at the last full sighting


@dataclass(frozen=True)
class Hud:
    """What the HUD needs beyond the step: where the pad is, the episode's length, the image."""

    pad_down_m: float = -1.5
    max_steps: int = 500
    control_rate_hz: float = 10.5
    fills_radius_px: float = 200.0  # a pad this big covers a 320x240 image corner to corner


def _finite(x: float | None, digits: int = 4) -> float | None:
    return None if x is None or not math.isfinite(x) else round(float(x), digits)


def _pad_fills(view: StepView, hud: Hud, watch: _EpisodeWatch | None, height_m: float) -> bool:
    """No pad seen, but the last full sighting says it is now larger than the image (or the
    vehicle is on it): "pad fills the image", not "pad not visible"."""
    if view.observation.pad is not None or watch is None or watch.pad_k_px_m is None:
        return False
    return height_m <= 0.05 or watch.pad_k_px_m / height_m >= hud.fills_radius_px


def step_message(view: StepView, learner_loss: float | None, samples: int, hud: Hud | None = None,
                 watch: _EpisodeWatch | None = None) -> dict[str, Any]:
    """One control step as the page's ``step`` message."""
    hud = hud or Hud()
    obs, d = view.observation, view.decision
    who = "hold" if (d.source == "human" and view.human_hold) else ("person" if d.source == "human" else "policy")
    pad = None if obs.pad is None else {"u": round(obs.pad.u_px, 1), "v": round(obs.pad.v_px, 1),
                                        "r": round(obs.pad.radius_px, 1), "partial": obs.pad.partial}
    n, e, dn = obs.position_ned_m
    vn, ve, vd = obs.velocity_ned_m_s
    height = dn * -1.0 + hud.pad_down_m
    return {
        "type": "step", "episode": view.episode, "step": view.step, "phase": view.phase.value,
        "who": who, "recorded": d.record, "tag": d.tag, "override": view.human_override,
        "altitude_m": round(-dn, 3), "climb_m_s": round(0.0 - vd, 3), "height_above_pad_m": round(height, 3),
        "ground_speed_m_s": round(math.hypot(vn, ve), 3), "heading_deg": round(math.degrees(obs.attitude_rad[2]) % 360.0, 1),
        "time_left_s": round(max(0, hud.max_steps - view.step - 1) / hud.control_rate_hz, 1),
        "pad_fills_image": _pad_fills(view, hud, watch, height), "frame_number": view.frame_number,
        "position_ne_m": [round(n, 3), round(e, 3)], "yaw_rad": round(obs.attitude_rad[2], 4),
        "pad": pad, "image_size_px": list(obs.image_size_px), "time_boot_ms": obs.time_boot_ms,
        "policy_version": view.policy_version, "loss": _finite(learner_loss, 6), "samples": samples,
        "wall_ms": round(time.time() * 1000.0, 1),  # just after the setpoint went out (latency bench)
        "setpoint": {"forward_m_s": round(view.setpoint.forward_m_s, 3), "right_m_s": round(view.setpoint.right_m_s, 3),
                     "down_m_s": round(view.setpoint.down_m_s, 3), "yaw_rate_rad_s": round(view.setpoint.yaw_rate_rad_s, 3)},
    }


class ConsoleSession:
    """Start, pause, next, stop; and the run's eyes and hands for the page."""

    def __init__(self, cfg: CompanionConfig, opts: ConsoleOptions, publish: Publish,
                 publish_frame: PublishFrame, study: ConsoleStudy | None = None) -> None:
        """``study``: ``col study``'s protocol decides what Start flies, where, and what follows."""
        self.cfg, self.opts = cfg, opts
        self.study = study
        self._run_dir = opts.run_dir  # the folder the current (or last) run writes to
        self.publish, self.publish_frame = publish, publish_frame
        self.human = BrowserInput(cfg.pilot)
        self.hud = Hud(cfg.session.pad_ned_m[2], cfg.session.max_steps, cfg.session.control_rate_hz)
        self.records: list[dict[str, Any]] = load_history(opts.run_dir)
        self._watch = _EpisodeWatch()
        self._rtp: Any = None
        self._lock = threading.Lock()
        self._resume = threading.Condition(self._lock)
        self._run = _RunState()
        self._paused = self._stop = self._next = self._go = False
        self._thread: threading.Thread | None = None
        self._pump: FramePump | None = None
        self._vehicle: Vehicle | None = None
        self._learner: Learner | None = None
        self._dataset: HumanDataset | None = None
        self._recorder: FlightRecorder | None = None  # this run's flight.png and last episode's video

    # ----- the page's commands ---------------------------------------------------------------
    def start(self, condition: str, episodes: int, auto: bool = False) -> None:
        """Start a run (ConfigError for a bad request or while one runs); ``auto``: no ready
        gate between episodes."""
        if condition not in PERSON_CONDITIONS:
            raise ConfigError(f"condition must be one of {', '.join(PERSON_CONDITIONS)}, got {condition!r}")
        if not isinstance(episodes, int) or isinstance(episodes, bool) or not 1 <= episodes <= 1000:
            raise ConfigError(f"episodes must be a whole number from 1 to 1000, got {episodes!r}")
        with self._lock:
            if self._thread is not None and self._thread.is_alive():
                raise ConfigError("a run is already going; stop it first")
            block, seed = None, self.opts.seed
            self._run_dir = self.opts.run_dir
            if self.study is not None:
                block = self.study.check_start(condition, episodes)
                self._run_dir, seed = self.study.run_dir(block), self.study.seed(block)
            self._run = _RunState("starting", condition, episodes, auto=auto, started_wall_s=time.time(),
                                  stage="starting the simulator and connecting (a few seconds)")
            self._paused = self._stop = self._next = False
            self._go = True  # Start is the first episode's "go"
            self._thread = threading.Thread(target=self._run_thread, args=(condition, episodes, seed, block),
                                            name="console-run", daemon=True)
            self._thread.start()
        self._announce(f"starting {condition} with {episodes} episodes")

    def go(self) -> None:
        """The pilot is ready: the waiting episode starts."""
        with self._lock:
            if self._run.state != "ready":
                raise ConfigError("no episode is waiting for you (go is for the ready gate between episodes)")
            self._go = True
            self._resume.notify_all()
        self._announce("the pilot is ready: the next episode starts")

    def set_auto(self, on: bool) -> None:
        """Auto mode: episodes follow one another without the pilot's go."""
        with self._lock:
            self._run.auto = on
            self._resume.notify_all()
        self._announce("auto: episodes follow one another" if on else "the pilot starts each episode")

    def discard_last(self, reason: str) -> None:
        """Take the last finished episode out of training (an audit line; nothing deleted)."""
        with self._lock:
            if self._run.state in ("starting", "running", "stopping"):
                raise ConfigError("an episode is flying; discard it after it ends (at the ready gate or after the run)")
            last = self.records[-1] if self.records else None
            dataset = self._dataset
        if last is None:
            raise ConfigError("no finished episode to discard")
        if self.study is not None and self.study.trial_written():
            raise ConfigError("the block is finished and its trial written (its policy was evaluated on what it "
                              "learned): discard between a block's episodes")
        if last.get("discarded"):
            raise ConfigError(f"episode {last['episode']} was discarded already")
        rows = self._discard(int(last["episode"]), reason, dataset)
        with self._lock:
            last["discarded"] = reason
        self.publish({"type": "discarded", "episode": last["episode"], "rows": rows, "reason": reason})
        self._announce(f"episode {last['episode']} discarded: {rows} samples out of training (kept in "
                       "human.csv, listed in human.discarded.jsonl)")

    def _discard(self, episode: int, reason: str, dataset: HumanDataset | None) -> int:
        try:
            if dataset is not None:
                return dataset.discard_episode(episode, reason)
            with HumanDataset(self._run_dir / "human.csv") as stored:  # after a restart, between runs
                return stored.discard_episode(episode, reason)
        except ValueError as exc:
            raise ConfigError(str(exc)) from None

    def pause(self, paused: bool) -> None:
        """Pause takes effect between episodes: the next one waits until resumed."""
        with self._lock:
            self._paused = paused
            self._resume.notify_all()
        self._announce("paused: the next episode waits" if paused else "resumed")

    def next_episode(self) -> None:
        with self._lock:
            if self._run.state != "running":
                raise ConfigError("no episode is flying")
            self._next = True
        self._announce("ending this episode")

    def stop(self) -> None:
        with self._lock:
            if self._run.state not in RUNNING_STATES:
                raise ConfigError("no run to stop")
            self._stop = True
            self._resume.notify_all()
            if self._run.state in ("starting", "running", "paused"):
                self._run.state = "stopping"
        self._announce("stopping the run")

    def hand_back(self) -> None:
        self.human.hand_back()
        self._announce("control handed back to the policy")

    def close(self, timeout_s: float = 30.0) -> None:
        """Stop any run and wait for it (its SITL stops with it)."""
        with self._lock:
            self._stop = True
            self._resume.notify_all()
        thread = self._thread
        if thread is not None:
            thread.join(timeout_s)

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    # ----- RunControl -------------------------------------------------------------------------
    def started(self, vehicle: Vehicle, learner: Learner, dataset: HumanDataset) -> None:
        if self._recorder is not None:
            self._recorder.started(vehicle, learner, dataset)
        with self._lock:
            self._vehicle, self._learner, self._dataset = vehicle, learner, dataset
            self._run.state = "stopping" if self._stop else "running"
            self._run.stage = "connected: the episode's start (reset, take-off) takes a few seconds"
            self._publish_status_locked()  # the run's state and simulator reach the pages before any step
        if vehicle.camera is not None:
            self._pump = FramePump(vehicle.camera, self._on_frame)
            self._pump.start()
        else:
            self._announce("no camera: flying with the pad reported as not visible")

    def before_episode(self, episode: int, phase: Phase) -> bool:
        with self._lock:
            if self._paused and not self._stop:
                self._run.state = "paused"
                self._publish_status_locked()
            self._resume.wait_for(lambda: self._stop or not self._paused)
            if not (self._stop or self._go or self._run.auto):
                self._run.state, self._run.ready_for, self._run.phase = "ready", episode, phase.value
                self._publish_status_locked()
            self._resume.wait_for(lambda: self._stop or self._go or self._run.auto)
            if self._stop:
                return False
            self._run.state, self._run.episode, self._run.phase = "running", episode, phase.value
            self._run.ready_for, self._go = None, False
            self._run.track_ne = []
            self._next = False
            self._watch = _EpisodeWatch()
            self._publish_status_locked()  # the episode and phase reach the pages before its first step
        self.human.reset()
        if self._recorder is not None:
            self._recorder.before_episode(episode, phase)
        return True

    def on_step(self, view: StepView) -> None:
        learner, dataset = self._learner, self._dataset
        self._notice_step(view)
        message = step_message(view, learner.last_loss if learner is not None else None,
                               len(dataset) if dataset is not None else 0, self.hud, self._watch)
        if message["who"] == "hold":  # the page's banner names why (refused sticks, the role given up...)
            message["hold_reason"] = self.human.why_holding()
        if self._recorder is not None:
            self._recorder.on_step(view)
        with self._lock:
            self._run.track_ne.append([*message["position_ne_m"], message["who"]])
            self._run.last_step = message
            self._run.stage = None
        self.publish(message)

    def _notice_step(self, view: StepView) -> None:
        """Count the person's recorded steps and stick movement; remember the pad's size."""
        w = self._watch
        if view.decision.record:
            w.recorded += 1
            if max(abs(x) for x in view.decision.command.to_array()) > self.cfg.commands.deadband:
                w.moved += 1
        pad, height = view.observation.pad, self.hud.pad_down_m - view.observation.position_ned_m[2]
        if pad is not None and not pad.partial and height > 0.05:
            w.pad_k_px_m = pad.radius_px * height

    def on_gap(self, gap: Gap | None) -> None:
        """The vehicle side stopped the steps being recorded (stale telemetry, a lost vehicle
        link, a missing camera frame), or they are whole again: the page shows why."""
        with self._lock:
            self._run.gap = None if gap is None else {"kind": gap.kind, "text": gap.text, "holding": gap.holding}
        self.publish({"type": "gap", "gap": self._run.gap})

    def end_requested(self) -> str | None:
        with self._lock:
            if self._stop or self._next:
                self._next = False
                return STOPPED
        return None

    # ----- run thread -------------------------------------------------------------------------
    def _run_thread(self, condition: str, episodes: int, seed: int | None, block: Block | None) -> None:
        opts = RunOptions(connection=self.opts.connection, simulator=self.opts.simulator, pilot="browser",
                          condition=condition, episodes=episodes, run_dir=self._run_dir,
                          config_path=self.opts.config_path, seed=seed, lockstep=False,
                          learn=self.opts.learn, camera_rate_hz=self.opts.camera_rate_hz)
        state, error = "finished", None
        self._recorder = FlightRecorder() if self.opts.pictures else None
        try:
            cfg = self.study.config(block) if self.study is not None and block is not None else self.cfg
            result = run_episodes(cfg, opts, self._on_episode, human=self.human, control=self)
            self._write_pictures(result, condition)
            if self.study is not None and block is not None:
                self._finish_block(block)
        except ColError as exc:
            state, error = "failed", str(exc)
            log.error("the console's run failed: %s", exc)
        except Exception as exc:  # shown in the page, never lost in a thread
            state, error = "failed", repr(exc)
            log.exception("the console's run failed")
        finally:
            if self._pump is not None:
                self._pump.stop()
                self._pump = None
            if self._rtp is not None:
                self._rtp.close()
                self._rtp = None
            with self._lock:
                self._run.state, self._run.error = state, error
                self._run.ready_for = self._run.stage = None
                self._run.gap = None  # no steps: nothing is missing from them
                self._run.summary = self._summary_locked(state, error)
                self._vehicle = None
                self._publish_status_locked()
        self._announce(self._run.summary or f"run {state}")

    def _finish_block(self, block: Block) -> None:
        """col study: a complete condition block's policy flies the held-out starts (a trial line)."""
        assert self.study is not None
        if block.trial is not None and self.study.folder.flown(block) >= block.episodes:
            with self._lock:
                self._run.stage = (f"evaluating the final policy alone on {self.study.setup.exp.eval_runs} "
                                   "held-out starts")
                self._publish_status_locked()
        line = self.study.after_run(block)
        if line is not None:
            self._announce(f"block {block.name}: the final policy landed {line['eval_successes']} of "
                           f"{line['eval_runs']} held-out starts alone; now the questionnaire (or skip it)")

    def answer_questionnaire(self, answers: Any) -> None:
        """col study: the participant's NASA-TLX after a block (None: skipped)."""
        if self.study is None:
            raise ConfigError("no study: the questionnaire belongs to `col study`")
        with self._lock:
            if self._thread is not None and self._thread.is_alive():
                raise ConfigError("the questionnaire comes after the block's run")
            line = self.study.answer(answers)
            self._publish_status_locked()
        self._announce(f"questionnaire after {line['block']} " + ("skipped" if line["skipped"] else "saved"))

    def _summary_locked(self, state: str, error: str | None) -> str:
        """The message at the end of a run: what was flown and what landed."""
        started = self._run.started_wall_s or 0.0
        mine = [r for r in self.records if r.get("console_run_s") == started]
        landed = sum(1 for r in mine if r.get("success"))
        text = f"run {state}: {len(mine)} of {self._run.episodes} episodes flown, {landed} landed on the pad"
        return text + (f"; {error}" if error else "")

    def _write_pictures(self, result: RunResult, condition: str) -> None:
        if self._recorder is None or not result.records:
            return
        first, last = result.records[0].episode, result.records[-1].episode
        for path in write_pictures(self._recorder, result, self.cfg, f"console {condition}"):
            if path.name == "flight.png":  # one picture per run, not overwritten by the next
                path = path.replace(path.with_name(f"flight_{first:03d}-{last:03d}.png"))
            self._announce(f"wrote {path}")

    def _on_frame(self, frame: Frame, message: bytes) -> None:
        self.publish_frame(message)
        if self.opts.rtp:
            self._send_rtp(frame)

    def _send_rtp(self, frame: Frame) -> None:
        """The camera to a ground station too (``--rtp``); its encoder runs on its own thread."""
        if self._rtp is None:
            from sitl.rtp import RtpVideoSender

            height, width = frame.image.shape[:2]
            self._rtp = RtpVideoSender(self.opts.rtp, width, height, self.opts.camera_rate_hz)
            self._announce(f"sending the camera as H.264 over RTP to {self.opts.rtp}")
        if self._rtp.error is None:
            self._rtp.publish(frame.image)

    def _on_episode(self, record: EpisodeRecord) -> None:
        with self._lock:
            last, w = self._run.last_step, self._watch
            touchdown = last["position_ne_m"] if (record.outcome == "touchdown" and last is not None) else None
            notes = {"episode": record.episode, "touchdown_ne_m": touchdown,
                     "no_stick_input": record.phase == Phase.DEMONSTRATION.value and w.moved == 0}
            entry = {**entry_of(record.to_json_dict()), **notes, "discarded": None,
                     "console_run_s": self._run.started_wall_s}
            self.records.append(entry)
        self._write_notes(notes)
        if self.study is not None:
            self.study.refresh()  # the block's episode count moved
        self.publish({"type": "episode", **entry})
        if notes["no_stick_input"]:
            self._announce(f"episode {record.episode} was a demonstration with no stick input "
                           f"({w.recorded} samples of centred sticks): discard it if nobody was flying")

    def _write_notes(self, notes: dict[str, Any]) -> None:
        try:
            with (self._run_dir / NOTES_FILE).open("a") as f:
                f.write(json.dumps(notes) + "\n")
        except OSError as exc:  # the dataset and episodes.jsonl are safe; the notes are a courtesy
            log.warning("could not write the console's notes: %s", exc)

    # ----- what the page is told ---------------------------------------------------------------
    def _announce(self, text: str) -> None:
        log.info("console: %s", text)
        self.publish({"type": "notice", "text": text})

    def _publish_status_locked(self) -> None:
        self.publish(self._status_locked())

    def _status_locked(self) -> dict[str, Any]:
        run, inp = self._run, self.human.status()
        learner, dataset = self._learner, self._dataset
        simulator = self._vehicle.simulator if self._vehicle is not None else None
        since = None if run.started_wall_s is None else round(time.time() - run.started_wall_s, 1)
        return {
            "type": "status", "run": {"state": run.state, "condition": run.condition, "episodes": run.episodes,
                                      "error": run.error, "episode": run.episode, "phase": run.phase,
                                      "paused": self._paused, "auto": run.auto, "ready_for": run.ready_for,
                                      "stage": run.stage, "since_start_s": since, "summary": run.summary,
                                      "gap": run.gap},
            "input": {"connected": inp.connected, "fresh": inp.fresh, "holding": inp.holding,
                      "hold_reason": inp.hold_reason, "lost_reason": inp.lost_reason, "messages": inp.messages,
                      "override": inp.command.override_held},
            "learner": {"version": learner.latest_snapshot.version if learner is not None else None,
                        "loss": _finite(learner.last_loss, 6) if learner is not None else None,
                        "samples": len(dataset) if dataset is not None else None},
            "simulator": getattr(simulator, "address", None),
            "frames": self._pump.frames if self._pump is not None else 0,
            "run_dir": str(self._run_dir),
            "study": self.study.status() if self.study is not None else None,
        }

    def status(self) -> dict[str, Any]:
        with self._lock:
            return self._status_locked()

    def hello(self) -> dict[str, Any]:
        """Everything a page that just connected needs: settings, history, this episode's track."""
        c = self.cfg
        with self._lock:
            track, episode = list(self._run.track_ne), self._run.episode
            records = list(self.records)
        return {
            "type": "hello",
            "conditions": list(PERSON_CONDITIONS),
            "control_rate_hz": c.session.control_rate_hz,
            "deadband": c.commands.deadband, "expo": c.commands.expo,
            "trigger_threshold": c.pilot.gamepad_trigger_threshold,
            "input_timeout_s": c.pilot.manual_timeout_s,
            "pad_ned_m": list(c.session.pad_ned_m), "pad_radius_m": c.pilot.pad_radius_m,
            "fence_radius_m": c.safety.fence_radius_m, "episodes_default": c.session.episodes,
            "max_steps": c.session.max_steps,
            "track": track, "track_episode": episode, "records": records, "status": self.status(),
        }

    def truth(self) -> dict[str, Any] | None:
        """The SITL's ground truth (pad and vehicle) for the map; None without a simulator."""
        vehicle = self._vehicle
        if vehicle is None or vehicle.simulator is None:
            return None
        try:
            return vehicle.simulator.truth()
        except ColError:
            return None


RECORD_KEYS = ("episode", "phase", "outcome", "success", "steps", "human_samples", "interventions",
               "touchdown_distance_m", "dataset_size", "policy_version", "loss_all")


def entry_of(record: dict[str, Any]) -> dict[str, Any]:
    """The table's columns of one ``episodes.jsonl`` record."""
    return {k: record.get(k) for k in RECORD_KEYS}


def _json_lines(path: Path) -> list[dict[str, Any]]:
    """A JSON-lines file's objects; unreadable lines (a torn last one) are logged and skipped."""
    if not path.is_file():
        return []
    out = []
    for i, line in enumerate(path.read_text().splitlines(), start=1):
        try:
            value = json.loads(line)
        except ValueError:
            log.warning("%s: line %d unreadable, skipped", path, i)
            continue
        if isinstance(value, dict) and isinstance(value.get("episode"), int):
            out.append(value)
    return out


def load_history(run_dir: Path) -> list[dict[str, Any]]:
    """The run folder's finished episodes for the table and plot: ``episodes.jsonl``, the
    console's notes and which episodes were discarded (a console restarted on the folder)."""
    notes = {n["episode"]: n for n in _json_lines(run_dir / NOTES_FILE)}
    audit = {int(a["episode"]): str(a.get("reason") or "discarded")
             for a in _json_lines(run_dir / "human.discarded.jsonl")}
    history = []
    for record in _json_lines(run_dir / "episodes.jsonl"):
        note = notes.get(record["episode"], {})
        history.append({**entry_of(record), "touchdown_ne_m": note.get("touchdown_ne_m"),
                        "no_stick_input": bool(note.get("no_stick_input")),
                        "discarded": audit.get(record["episode"])})
    return history
