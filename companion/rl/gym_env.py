"""The landing task (companion/rl/landing_task.py) as a Gymnasium environment, over the real
MAVLink path to a lockstep SITL (or the same code in this process).

A driver of the episode core (:class:`~companion.control.lanes.EpisodeLanes`) with one lane, the
vehicle behind its link (:class:`~companion.control.link_lane.LinkLane`: the session's episode
start, frames and camera frame): ``reset`` is the lane's start, one ``step`` is one control tick,
the action's sticks through the core's setpoint arithmetic (the session's mapper and limiter, row
by row), then the next frame's observation and its judgement by the one rule of
companion/control/outcome.py, scored by the one scoring rule on the SITL's ground truth. The
batched env flies the same core on direct lanes.

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
    RunOptions,
    Vehicle,
    expected_image_size,
    open_run_camera,
    simulator_client,
    vehicle_connection,
)
from companion.config import CompanionConfig
from companion.control import outcome as outcome_rule
from companion.control.lanes import EpisodeLanes
from companion.control.link_lane import LinkLane
from companion.errors import ColError, ConfigError, LinkLost
from companion.inprocess import inprocess_vehicle
from companion.link import open_link
from companion.rl.landing_task import (
    ACTION_AXES,
    DESCENT_THROTTLE,
    check_task,
    observation_space,
    outcome_info,
    stick_rows,
    stick_values,
)

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
            self.lane = self._connect(RunOptions(connection=connection, simulator=simulator, config_path=config_path))
        except BaseException:
            self._stack.close()
            raise
        self.core = EpisodeLanes(self.cfg, [self.lane])  # the position from home, as the session observes it
        # The first start after the SITL connects is handed over from real-time pacing and
        # differs slightly from all later ones: fly it once so that every reset(seed) repeats.
        self.core.begin(0, None, attempts=1)
        self._next_seed = self.cfg.session.seed
        self._seed: int | None = None
        self._done = True

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

    def _connect(self, opts: RunOptions) -> LinkLane:
        """The vehicle (over MAVLink sockets or in-process) as the core's lane."""
        if self.inprocess:
            vehicle = self._stack.enter_context(inprocess_vehicle(_never_lost(self.cfg), opts, True, Path(".")))
        else:
            vehicle = self._open_sockets(opts)
        assert vehicle.simulator is not None  # both openers give the SITL's control surface
        return LinkLane(self.cfg, vehicle.link, vehicle.simulator, vehicle.camera, expected_image_size(opts))

    # ----- Gymnasium API ---------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        start_seed = self._next_seed if seed is None else int(seed)
        self._next_seed = start_seed + 1
        self._seed, self._done = start_seed, False
        self.core.begin(0, start_seed)  # a starved SITL may miss one start: tried again
        return self._observe(), {"seed": start_seed}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self._done:
            raise ColError("the episode has ended: call reset() before step()")
        sticks = stick_values(action, self.action_dims, self.descent_throttle)
        try:
            self.core.fly(sticks[None, :])
        except LinkLost:  # no frame in time (a starved SITL): cut the episode short, not a failure
            log.warning("step %d: no frame from the SITL in time; truncating the episode", self.core.steps[0] + 1)
            self._done = True
            return self.core.last_obs[0].copy(), 0.0, False, True, self._info("link_lost", self.core.steps[0] + 1)[0]
        obs = self._observe()
        outcome = self.core.judge([0])[0]
        self._done = outcome is not None
        info, reward = self._info(outcome, self.core.steps[0])
        terminated = outcome in (outcome_rule.TOUCHDOWN, outcome_rule.FENCE)
        return obs, reward, terminated, outcome == outcome_rule.TIMEOUT, info

    def ground_truth(self) -> dict[str, Any]:
        """The SITL's truth (vehicle and pad NED, touchdown): for tests and diagnostics; the
        agent never sees it."""
        return self.lane.ground_truth()

    def close(self) -> None:
        """Stop the link, camera and (our) SITL; safe to call twice."""
        self._done = True
        self._stack.close()

    # ----- pieces ----------------------------------------------------------------------------
    def _observe(self) -> np.ndarray:
        """The 15 values of the latest frame (the position from home, as every driver observes it);
        non-finite telemetry repeats the last good ones."""
        vectors, _ = self.core.observe([0])
        return vectors[0].copy()

    def _info(self, outcome: str | None, steps: int) -> tuple[dict[str, Any], float]:
        """What happened, and the reward: scored by the one rule (companion/control/outcome.py)
        on the SITL's ground truth once the episode has ended."""
        return outcome_info(self._seed, steps, outcome, self.core.score(0, outcome or ""))
