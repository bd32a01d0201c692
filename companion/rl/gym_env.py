"""The landing task (companion/rl/landing_task.py) as a Gymnasium environment, over the real
MAVLink path to a lockstep SITL (or the same code in this process).

A driver of the session's episode loop: ``reset`` is :meth:`EpisodeRunner.begin
<companion.control.session.EpisodeRunner.begin>`, one ``step`` is one control tick answered with
:meth:`~companion.control.session.EpisodeRunner.answer` (the action's sticks through the same
CommandMapper and SetpointLimiter as a person's or the policy's command), then the next frame's
observation (the session's observer) and its judgement by the one rule of
companion/control/outcome.py, scored by the one scoring rule on the SITL's ground truth.

``reset(seed=s)`` starts the SITL's episode ``s`` (the same starts as ``col eval --seed s``);
``reset()`` without a seed continues with the next seed (the first is ``session.seed``).
"""

from __future__ import annotations

import contextlib
import logging
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from companion.app import (
    NoHuman,
    RunOptions,
    Vehicle,
    expected_image_size,
    open_run_camera,
    simulator_client,
    vehicle_connection,
)
from companion.commands import CommandMapper
from companion.config import CompanionConfig
from companion.control import outcome as outcome_rule
from companion.control.lanes import score_by_truth, start_with_retries
from companion.control.parts import EpisodeParts
from companion.control.safety import Geofence, SetpointLimiter
from companion.control.session import EpisodeRunner
from companion.errors import ColError, ConfigError
from companion.inprocess import inprocess_vehicle
from companion.link import open_link
from companion.msg.observation import OBS_DIM
from companion.msg.snapshot import VehicleSnapshot
from companion.rl.landing_task import (
    ACTION_AXES,
    DESCENT_THROTTLE,
    check_task,
    observation_space,
    outcome_info,
    stick_rows,
    stick_values,
)
from companion.simulator import SimulatorClient
from companion.vision.observer import Observer
from companion.vision.perception import PadDetector

log = logging.getLogger(__name__)
IN_PROCESS_LINK_LOST_S = 1e9
__all__ = ["ACTION_AXES", "DESCENT_THROTTLE", "LandingEnv", "observation_space", "outcome_info", "stick_rows",
           "stick_values"]  # the task's names (companion/rl/landing_task.py), where they were first


def _never_lost(cfg: CompanionConfig) -> CompanionConfig:
    """In one process the link cannot be lost, and the time the agent takes between steps (a PPO
    update: seconds on a busy machine) is no silence of the vehicle: no wall-clock link loss."""
    return cfg.model_copy(update={"link": cfg.link.model_copy(update={"link_lost_s": IN_PROCESS_LINK_LOST_S})})


class LandingEnv(gym.Env[np.ndarray, np.ndarray]):
    """Land on the pad from the paper's starts; one step = one control tick in lockstep.

    Without ``connection`` it starts its own lockstep SITL (stopped by :meth:`close`). With
    ``connection`` (a MAVLink connection string to a lockstep SITL) it also needs
    ``simulator`` (HOST:PORT of that SITL's control surface) for resets and ground truth.
    With ``inprocess=True`` the SITL runs in this process and thread
    (:mod:`companion.inprocess`: the same server, link and camera code, only the
    transport replaced): the same episodes, a fraction of the CPU per step.
    """

    metadata: dict[str, Any] = {"render_modes": []}

    def __init__(self, action_dims: int = 2, cfg: CompanionConfig | None = None, *,
                 descent_throttle: float = DESCENT_THROTTLE, connection: str | None = None,
                 simulator: str | None = None, config_path: Path | None = None, inprocess: bool = False) -> None:
        check_task(action_dims, descent_throttle)
        if connection is not None and simulator is None:
            raise ConfigError("an external SITL needs --simulator HOST:PORT too: resets and the reward come from its control surface")
        if inprocess and connection is not None:
            raise ConfigError("an in-process env flies its own SITL; it takes no connection")
        self.cfg = cfg or CompanionConfig()
        self.action_dims = action_dims
        self.descent_throttle = descent_throttle
        self.max_steps = self.cfg.session.max_steps
        self.action_space = gym.spaces.Box(-1.0, 1.0, (action_dims,), dtype=np.float32)
        self.observation_space = observation_space()
        self.inprocess = inprocess
        self._stack = contextlib.ExitStack()
        try:
            self._runner, self._simulator = self._connect(RunOptions(connection=connection, simulator=simulator,
                                                                     config_path=config_path))
        except BaseException:
            self._stack.close()
            raise
        self._next_seed = self.cfg.session.seed
        self._seed: int | None = None
        self._steps = 0
        self._done = True
        self._last_obs = np.zeros(OBS_DIM, dtype=np.float32)

    def _open_sockets(self, opts: RunOptions) -> Vehicle:
        """SITL (ours or given), link, control surface and camera, as ``col eval`` wires them."""
        connection, sitl = self._stack.enter_context(vehicle_connection(self.cfg, opts, lockstep=True))
        link = open_link(self.cfg.link.model_copy(update={"connection": connection}))
        self._stack.callback(link.close)
        link.connect(timeout_s=30.0)
        simulator = simulator_client(opts, sitl)
        assert simulator is not None  # ours, or the --simulator given (checked in __init__)
        self._stack.callback(simulator.close)
        camera = open_run_camera(self.cfg, sitl, link)
        if camera is not None:
            self._stack.callback(camera.close)
        return Vehicle(link, simulator, camera)

    def _connect(self, opts: RunOptions) -> tuple[EpisodeRunner, SimulatorClient]:
        """The vehicle (over MAVLink sockets or in-process) and the session's episode loop on it."""
        if self.inprocess:
            vehicle = self._stack.enter_context(inprocess_vehicle(_never_lost(self.cfg), opts, True, Path(".")))
        else:
            vehicle = self._open_sockets(opts)
        link, simulator, camera = vehicle.link, vehicle.simulator, vehicle.camera
        assert simulator is not None  # both openers give the SITL's control surface
        parts = EpisodeParts(
            link=link, observer=Observer(camera, PadDetector(self.cfg.perception), expected_image_size(opts),
                                        self.cfg.perception.frame_timeout_s),
            mapper=CommandMapper(self.cfg.commands), human=NoHuman(), fence=Geofence.from_config(self.cfg.safety),
            limiter=SetpointLimiter(self.cfg.commands, self.cfg.safety), cfg=self.cfg.session, lockstep=True,
            simulator=simulator,
        )
        runner = EpisodeRunner(parts)
        # The first start after the SITL connects is handed over from real-time pacing and
        # differs slightly from all later ones: fly it once so that every reset(seed) repeats.
        runner.begin(None)
        return runner, simulator

    # ----- Gymnasium API ---------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        start_seed = self._next_seed if seed is None else int(seed)
        self._next_seed = start_seed + 1
        self._seed, self._steps, self._done = start_seed, 0, False
        snap = start_with_retries(self._runner.begin, start_seed)  # a starved SITL may miss one start
        obs = self._observe(snap)
        return obs, {"seed": start_seed}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self._done:
            raise ColError("the episode has ended: call reset() before step()")
        values = stick_values(action, self.action_dims, self.descent_throttle)
        command = self._runner.p.mapper.command_from_values(values)
        snap = self._runner.answer(command)
        self._steps += 1
        if snap is None:  # no frame in time (a starved SITL): cut the episode short, not a failure
            log.warning("step %d: no frame from the SITL in time; truncating the episode", self._steps)
            self._done = True
            return self._last_obs.copy(), 0.0, False, True, self._info("link_lost")[0]
        obs = self._observe(snap)
        runner = self._runner
        outcome = outcome_rule.judge_snapshot(self._steps, self.max_steps, snap, runner.p.fence, runner.home)
        self._done = outcome is not None
        info, reward = self._info(outcome)
        terminated = outcome in (outcome_rule.TOUCHDOWN, outcome_rule.FENCE)
        return obs, reward, terminated, outcome == outcome_rule.TIMEOUT, info

    def ground_truth(self) -> dict[str, Any]:
        """The SITL's truth (vehicle and pad NED, touchdown): for tests and diagnostics; the
        agent never sees it."""
        return self._simulator.truth()

    def close(self) -> None:
        """Stop the link, camera and (our) SITL; safe to call twice."""
        self._done = True
        self._stack.close()

    # ----- pieces ----------------------------------------------------------------------------
    def _observe(self, snap: VehicleSnapshot) -> np.ndarray:
        """The 15 values of this frame (the position as reported: see EpisodeLanes.observe);
        non-finite telemetry repeats the last good ones."""
        try:
            vector = self._runner.p.observer.observe(snap, lockstep=True).to_vector()
        except ValueError as exc:
            log.warning("step %d: unusable telemetry (%s); repeating the last observation", self._steps, exc)
            return self._last_obs.copy()
        self._last_obs = vector
        return vector.copy()

    def _info(self, outcome: str | None) -> tuple[dict[str, Any], float]:
        """What happened, and the reward: scored by the one rule (companion/control/outcome.py)
        on the SITL's ground truth once the episode has ended."""
        return outcome_info(self._seed, self._steps, outcome, score_by_truth(outcome or "", self._simulator.truth))

