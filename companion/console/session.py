"""The console's session: one run of episodes at a time, on its own thread, driven by the page.

It is the run's :class:`~companion.app.RunControl`: it sees each control step (for the HUD, the
map and the per-episode table), pauses between episodes, ends an episode or the run when the
page asks, and hands the page's sticks to the run as its human input (:class:`BrowserInput`).
What it tells the page goes through ``publish`` (JSON-able dicts) and ``publish_frame``
(camera frames), both callable from any thread.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from companion.app import CONDITIONS, RunOptions, RunResult, Vehicle, run_episodes, write_pictures
from companion.config import CompanionConfig
from companion.console.frames import FramePump
from companion.control.arbiter import Phase
from companion.control.session import EpisodeRecord, StepView
from companion.errors import ColError, ConfigError
from companion.inputs.browser import BrowserInput
from companion.learning.dataset import HumanDataset
from companion.learning.learner import Learner
from companion.pictures.recorder import FlightRecorder
from sitl.frames import Frame

log = logging.getLogger(__name__)
Publish = Callable[[dict[str, Any]], None]
PublishFrame = Callable[[bytes], None]
STOPPED = "stopped"  # the outcome of an episode the operator ended


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
    pictures: bool = True  # each run writes flight.png and its last episode's video


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


def _finite(x: float | None, digits: int = 4) -> float | None:
    return None if x is None or not math.isfinite(x) else round(float(x), digits)


def step_message(view: StepView, learner_loss: float | None, samples: int) -> dict[str, Any]:
    """One control step as the page's ``step`` message."""
    obs, d = view.observation, view.decision
    who = "hold" if (d.source == "human" and view.human_hold) else ("person" if d.source == "human" else "policy")
    pad = None if obs.pad is None else {"u": round(obs.pad.u_px, 1), "v": round(obs.pad.v_px, 1),
                                        "r": round(obs.pad.radius_px, 1), "partial": obs.pad.partial}
    n, e, dn = obs.position_ned_m
    return {
        "type": "step", "episode": view.episode, "step": view.step, "phase": view.phase.value,
        "who": who, "recorded": d.record, "tag": d.tag, "override": view.human_override,
        "altitude_m": round(-dn, 3), "climb_m_s": round(-obs.velocity_ned_m_s[2], 3),
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
                 publish_frame: PublishFrame) -> None:
        self.cfg, self.opts = cfg, opts
        self.publish, self.publish_frame = publish, publish_frame
        self.human = BrowserInput(cfg.pilot)
        self.records: list[dict[str, Any]] = []
        self._lock = threading.Lock()
        self._resume = threading.Condition(self._lock)
        self._run = _RunState()
        self._paused = self._stop = self._next = False
        self._thread: threading.Thread | None = None
        self._pump: FramePump | None = None
        self._vehicle: Vehicle | None = None
        self._learner: Learner | None = None
        self._dataset: HumanDataset | None = None
        self._recorder: FlightRecorder | None = None  # this run's flight.png and last episode's video

    # ----- the page's commands ---------------------------------------------------------------
    def start(self, condition: str, episodes: int) -> None:
        """Start a run (ConfigError for a bad request or while one runs)."""
        if condition not in CONDITIONS or condition == "eval":
            raise ConfigError(f"condition must be demo, int or col, got {condition!r}")
        if not isinstance(episodes, int) or isinstance(episodes, bool) or not 1 <= episodes <= 1000:
            raise ConfigError(f"episodes must be a whole number from 1 to 1000, got {episodes!r}")
        with self._lock:
            if self._thread is not None and self._thread.is_alive():
                raise ConfigError("a run is already going; stop it first")
            self._run = _RunState("starting", condition, episodes)
            self._paused = self._stop = self._next = False
            self._thread = threading.Thread(target=self._run_thread, args=(condition, episodes),
                                            name="console-run", daemon=True)
            self._thread.start()
        self._announce(f"starting {condition} with {episodes} episodes")

    def pause(self, paused: bool) -> None:
        """Pause takes effect between episodes: the next one waits until resumed."""
        with self._lock:
            self._paused = paused
            self._resume.notify_all()
        self._announce("paused: the next episode waits" if paused else "resumed")

    def next_episode(self) -> None:
        with self._lock:
            self._next = True
        self._announce("ending this episode")

    def stop(self) -> None:
        with self._lock:
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
        self.stop()
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
            if self._stop:
                return False
            self._run.state, self._run.episode, self._run.phase = "running", episode, phase.value
            self._run.track_ne = []
            self._next = False
        self.human.reset()
        if self._recorder is not None:
            self._recorder.before_episode(episode, phase)
        return True

    def on_step(self, view: StepView) -> None:
        learner, dataset = self._learner, self._dataset
        message = step_message(view, learner.last_loss if learner is not None else None,
                               len(dataset) if dataset is not None else 0)
        if self._recorder is not None:
            self._recorder.on_step(view)
        with self._lock:
            self._run.track_ne.append([*message["position_ne_m"], message["who"]])
            self._run.last_step = message
        self.publish(message)

    def end_requested(self) -> str | None:
        with self._lock:
            if self._stop or self._next:
                self._next = False
                return STOPPED
        return None

    # ----- run thread -------------------------------------------------------------------------
    def _run_thread(self, condition: str, episodes: int) -> None:
        opts = RunOptions(connection=self.opts.connection, simulator=self.opts.simulator, pilot="browser",
                          condition=condition, episodes=episodes, run_dir=self.opts.run_dir,
                          config_path=self.opts.config_path, seed=self.opts.seed, lockstep=False,
                          learn=self.opts.learn, camera_rate_hz=self.opts.camera_rate_hz)
        state, error = "finished", None
        self._recorder = FlightRecorder() if self.opts.pictures else None
        try:
            result = run_episodes(self.cfg, opts, self._on_episode, human=self.human, control=self)
            self._write_pictures(result, condition)
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
            with self._lock:
                self._run.state, self._run.error = state, error
                self._vehicle = None
                self._publish_status_locked()
        self._announce(f"run {state}" + (f": {error}" if error else ""))

    def _write_pictures(self, result: RunResult, condition: str) -> None:
        if self._recorder is None or not result.records:
            return
        for path in write_pictures(self._recorder, result, self.cfg, f"console {condition}"):
            self._announce(f"wrote {path}")

    def _on_frame(self, frame: Frame, message: bytes) -> None:
        self.publish_frame(message)

    def _on_episode(self, record: EpisodeRecord) -> None:
        with self._lock:
            last = self._run.last_step
            touchdown = last["position_ne_m"] if (record.outcome == "touchdown" and last is not None) else None
            entry = {"episode": record.episode, "phase": record.phase, "outcome": record.outcome,
                     "success": record.success, "steps": record.steps, "human_samples": record.human_samples,
                     "interventions": record.interventions, "touchdown_distance_m": record.touchdown_distance_m,
                     "touchdown_ne_m": touchdown, "dataset_size": record.dataset_size,
                     "policy_version": record.policy_version, "loss_all": record.loss_all}
            self.records.append(entry)
        self.publish({"type": "episode", **entry})

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
        return {
            "type": "status", "run": {"state": run.state, "condition": run.condition, "episodes": run.episodes,
                                      "error": run.error, "episode": run.episode, "phase": run.phase,
                                      "paused": self._paused},
            "input": {"connected": inp.connected, "fresh": inp.fresh, "holding": inp.holding,
                      "hold_reason": inp.hold_reason, "messages": inp.messages, "override": inp.command.override_held},
            "learner": {"version": learner.latest_snapshot.version if learner is not None else None,
                        "loss": _finite(learner.last_loss, 6) if learner is not None else None,
                        "samples": len(dataset) if dataset is not None else None},
            "simulator": getattr(simulator, "address", None),
            "frames": self._pump.frames if self._pump is not None else 0,
            "run_dir": str(self.opts.run_dir),
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
            "conditions": ["demo", "int", "col"],
            "control_rate_hz": c.session.control_rate_hz,
            "deadband": c.commands.deadband, "expo": c.commands.expo,
            "trigger_threshold": c.pilot.gamepad_trigger_threshold,
            "input_timeout_s": c.pilot.manual_timeout_s,
            "pad_ned_m": list(c.session.pad_ned_m), "pad_radius_m": c.pilot.pad_radius_m,
            "fence_radius_m": c.safety.fence_radius_m, "episodes_default": c.session.episodes,
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
