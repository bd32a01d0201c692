"""The landing task for N envs in one process: the batched, session-free vec env.

:class:`~companion.rl.gym_env.LandingEnv` with ``inprocess=True`` flies one step as follows. The
action becomes four stick values (:func:`~companion.rl.gym_env.stick_values`), the
:class:`~companion.commands.CommandMapper` repairs them (non-finite -> 0, clamped to [-1, 1],
counted and logged) and shapes them (deadband -> expo -> scale -> clip) into a body-velocity
setpoint, the session's :class:`~companion.control.safety.SetpointLimiter` clips it and limits its
rate of change, the link checks it against its own limits and sends SET_POSITION_TARGET_LOCAL_NED
(every float rounded to float32 on the wire); the SITL's message handler gives it to the vehicle,
which rotates it by its heading now; the server runs the next frame (12 FDM steps of JSBSim with
the autopilot cascade, the streams that are due, the camera image with its latency and pixel
noise, the SYSTEM_TIME marker); the link folds the messages into a snapshot; the session moves
its home frame; the observer detects the pad in the frame stamped with the marker's time and
builds the 15 values; the env judges the frame and scores the episode by the one rule of
:mod:`companion.control.outcome` (the time limit, the landed state ON_GROUND, the geofence; the
reward is 1 for a touchdown the SITL judges successful).

:class:`BatchedLandingEnv` does the same arithmetic without the objects that carry it there. For
each env a :class:`~companion.rl.landing_lane.LandingLane` holds the SITL's own vehicle, scheduler
and renderer, driven directly (:mod:`companion.rl.direct_sitl`: no server, MAVLink messages,
link, session or observer), and the session's home frame, geofence and episode start. Per step,
for all envs at once, the actions go through the very functions the single env uses, on stacks
of values: the sticks (:func:`~companion.rl.gym_env.stick_rows`), the mapper's shaping
(:meth:`CommandMapper.physical`, :func:`~companion.commands.body_velocity`), the limiter's clip and
rate limit (:meth:`SetpointLimiter.clipped`, :meth:`SetpointLimiter.rate_limited`), the link's
limits; each env's vehicle then flies its frame; each env's image goes through the one
:class:`~companion.vision.perception.PadDetector`; the vectors are made by
:func:`~companion.vision.observation.pad_features` and
:func:`~companion.vision.observation.normalised` for all envs. These are element-by-element
operations (IEEE arithmetic, clips, comparisons): a row of a stack comes out as the value alone,
bit for bit. Repairs of bad actions still go through each env's own mapper (so they are counted
and logged per env); everything that depends on an env's history (vehicle, camera, telemetry
schedule, home frame) stays per env. Each env also flies what ``LandingEnv`` flies before its
first episode (the frame in which the link hears the vehicle, the streams it asks for, one
warm-up start), so its simulation clock, from which episode starts are taken, is the same too.

So for the same seeds and actions it flies the same episodes as ``LandingEnv(inprocess=True)``:
the same observations, rewards, terminations, outcomes and touchdowns
(``tests/rl/test_batched_env.py`` checks them step by step). What it leaves out changes no
episode: the MAVLink framing, the ACKs and STATUSTEXTs, the wall-clock times the link keeps, the
"link lost" outcome (a frame cannot be late in one thread), the images of frames nobody observes,
and a ``ColError`` for a step after the end (a vec env resets instead).

As a stable-baselines3 ``VecEnv`` it behaves like ``DummyVecEnv`` of ``LandingEnv``s: ``seed(s)``
then ``reset()`` starts env ``k`` from ``s + k``; an env that is done is reset at once, with its
next seed, its last observation in ``info["terminal_observation"]``. Several processes, each with
a batch, are :func:`batched_workers` (one per core).
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Callable, Sequence
from functools import partial
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.utils import seeding
from stable_baselines3.common.vec_env import VecEnv
from stable_baselines3.common.vec_env.base_vec_env import VecEnvIndices, VecEnvObs, VecEnvStepReturn

from companion.app import RunOptions
from companion.config import CompanionConfig
from companion.control import outcome as outcome_rule
from companion.control.setpoint_rows import SetpointRows
from companion.errors import ColError, ConfigError
from companion.inprocess import one_opencv_thread, sitl_config_for
from companion.link.base import VehicleSnapshot
from companion.rl.grouped_vec_env import GroupedSubprocVecEnv, group_sizes
from companion.rl.gym_env import (
    ACTION_AXES,
    DESCENT_THROTTLE,
    observation_space,
    outcome_info,
    stick_rows,
)
from companion.rl.landing_lane import LandingLane
from companion.vision.observation import normalised
from companion.vision.observation_rows import detect_pad, pad_rows, telemetry_row
from companion.vision.perception import PadDetection, PadDetector

log = logging.getLogger(__name__)


class BatchedLandingEnv(VecEnv):
    """``n_envs`` landing envs stepped together in this process (module docstring): the episodes
    of ``n_envs`` ``LandingEnv(inprocess=True)`` in a ``DummyVecEnv``, without their session,
    link and telemetry messages."""

    def __init__(self, n_envs: int, action_dims: int = 2, cfg: CompanionConfig | None = None, *,
                 descent_throttle: float = DESCENT_THROTTLE, config_path: Path | None = None) -> None:
        cfg = cfg or CompanionConfig()
        _check(n_envs, action_dims, descent_throttle, cfg)
        self.cfg, self.action_dims, self.descent_throttle = cfg, action_dims, descent_throttle
        self.max_steps = cfg.session.max_steps
        self.period_s = 1.0 / cfg.session.control_rate_hz
        self._stack = contextlib.ExitStack()
        self._stack.enter_context(one_opencv_thread())  # as the in-process SITL renders
        try:
            sitl_cfg = sitl_config_for(cfg, RunOptions(config_path=config_path))
            self.lanes = [LandingLane(cfg, sitl_cfg, action_dims, descent_throttle) for _ in range(n_envs)]
        except BaseException:
            self._stack.close()
            raise
        self._setpoint_rows = SetpointRows(cfg, n_envs)  # each env's mapper and limiter, row by row
        self._detector = PadDetector(cfg.perception)
        self._image_size = (self.lanes[0].sitl.cfg.camera.width_px, self.lanes[0].sitl.cfg.camera.height_px)
        self._sticks = np.zeros((n_envs, 4))
        self.closed = False
        action_space = gym.spaces.Box(-1.0, 1.0, (action_dims,), dtype=np.float32)
        super().__init__(n_envs, observation_space(), action_space)

    # ----- stable-baselines3's VecEnv --------------------------------------------------------
    def reset(self) -> VecEnvObs:
        """Every env from its seed (``seed(s)``: ``s + k``), else its next one, as ``DummyVecEnv``."""
        indices = list(range(self.num_envs))
        for i in indices:
            self.reset_infos[i] = self._begin(i, self._seeds[i])
        obs = self._observe(indices)
        self._reset_seeds()
        self._reset_options()
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        """Checked and turned into sticks now, so a bad action fails the call that gave it."""
        if self.closed:
            raise ColError("the batched env is closed; make a new one")
        self._sticks = self._repaired(stick_rows(self._action_rows(actions), self.descent_throttle))

    def step_wait(self) -> VecEnvStepReturn:
        setpoints = self._setpoint_rows.setpoints(self._sticks)
        snaps = [self._fly(lane, sp) for lane, sp in zip(self.lanes, setpoints.tolist(), strict=True)]
        obs = self._observe(list(range(self.num_envs)))
        rewards = np.zeros(self.num_envs, dtype=np.float32)
        dones = np.zeros(self.num_envs, dtype=bool)
        infos: list[dict[str, Any]] = []
        for i, (lane, snap) in enumerate(zip(self.lanes, snaps, strict=True)):
            outcome = outcome_rule.judge_snapshot(lane.steps, lane.max_steps, snap, lane.fence, lane.home)
            touchdown = lane.ground_truth().get("touchdown") if outcome == outcome_rule.TOUCHDOWN else None
            info, rewards[i] = outcome_info(lane.seed, lane.steps, outcome, touchdown)
            dones[i] = outcome is not None
            info["TimeLimit.truncated"] = outcome == outcome_rule.TIMEOUT
            infos.append(info)
        self._reset_done(obs, dones, infos)
        return obs, rewards, dones, infos

    def close(self) -> None:
        """Nothing runs outside this process; OpenCV gets its threads back. Safe to call twice."""
        self.closed = True
        self._stack.close()

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        """An attribute of each env (a :class:`LandingLane`: ``max_steps``, ``action_dims``, ...)."""
        return [getattr(self.lanes[i], attr_name) for i in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        for i in self._get_indices(indices):
            setattr(self.lanes[i], attr_name, value)

    def env_method(self, method_name: str, *method_args: Any, indices: VecEnvIndices = None,
                   **method_kwargs: Any) -> list[Any]:
        """A method of each env, e.g. ``ground_truth``."""
        return [getattr(self.lanes[i], method_name)(*method_args, **method_kwargs) for i in self._get_indices(indices)]

    def env_is_wrapped(self, wrapper_class: type[gym.Wrapper[Any, Any, Any, Any]],
                       indices: VecEnvIndices = None) -> list[bool]:
        return [False for _ in self._get_indices(indices)]

    # ----- actions -> setpoints -----------------------------------------------------------------
    def _action_rows(self, actions: np.ndarray) -> np.ndarray:
        """``(n_envs, action_dims)`` float64; ValueError naming the shape wanted otherwise."""
        a = np.asarray(actions, dtype=np.float64)
        if a.ndim == 0 or a.shape[0] != self.num_envs or a[0].size != self.action_dims:
            raise ValueError(f"expected actions of shape ({self.num_envs}, {self.action_dims}): one row of "
                             f"{ACTION_AXES[:self.action_dims]} per env, got shape {a.shape}")
        return a.reshape(self.num_envs, self.action_dims)

    def _repaired(self, sticks: np.ndarray) -> np.ndarray:
        """Rows with a non-finite or out-of-range value go through their env's mapper (repaired,
        counted, logged, as ``LandingEnv`` does); the others are valid commands already."""
        bad = ~(np.isfinite(sticks) & (np.abs(sticks) <= 1.0)).all(axis=1)
        for i in np.flatnonzero(bad):
            sticks[i] = self.lanes[i].mapper.command_from_values(sticks[i]).to_array()
        return sticks

    @staticmethod
    def _fly(lane: LandingLane, setpoint: list[float]) -> VehicleSnapshot:
        """Send one env's setpoint and run its next frame."""
        forward, right, down, yaw_rate = setpoint
        lane.velocity((forward, right, down), yaw_rate)
        lane.steps += 1
        return lane.next_frame()

    # ----- episodes -------------------------------------------------------------------------------
    def _begin(self, i: int, seed: int | None) -> dict[str, Any]:
        """``LandingEnv.reset(seed=seed)`` for env ``i``, but for the observation: its reset info."""
        lane = self.lanes[i]
        if seed is not None:
            seeding.np_random(seed)  # the same check of the seed as gymnasium's Env.reset
        start = lane.next_seed if seed is None else int(seed)
        lane.next_seed, lane.seed, lane.steps = start + 1, start, 0
        self._setpoint_rows.forget(i)  # the session's limiter starts afresh
        lane.begin(start)
        return {"seed": start}

    def _reset_done(self, obs: np.ndarray, dones: np.ndarray, infos: list[dict[str, Any]]) -> None:
        """Each finished env: its last observation into its info, then its next episode."""
        done = np.flatnonzero(dones).tolist()
        for i in done:
            infos[i]["terminal_observation"] = obs[i].copy()
            self.lanes[i].ended_truth = self.lanes[i].ground_truth()
            self.reset_infos[i] = self._begin(i, None)
        if done:
            obs[done] = self._observe(done)

    # ----- observations ---------------------------------------------------------------------------
    def _observe(self, indices: list[int]) -> np.ndarray:
        """The observation vectors of these envs' latest frames; a vector that is not finite
        repeats that env's last good one (``LandingEnv._observe``)."""
        telemetry = np.array([telemetry_row(self.lanes[i].sitl.reported) for i in indices])
        pads = pad_rows([self._detect(self.lanes[i]) for i in indices], self._image_size)
        vectors = normalised(telemetry, pads)
        for row, i in enumerate(indices):
            lane = self.lanes[i]
            if np.isfinite(vectors[row]).all():
                lane.last_obs = vectors[row].copy()
            else:
                log.warning("step %d: unusable telemetry; repeating the last observation", lane.steps)
                vectors[row] = lane.last_obs
        return vectors

    def _detect(self, lane: LandingLane) -> PadDetection | None:
        return detect_pad(self._detector, lane.sitl.image())


def _check(n_envs: int, action_dims: int, descent_throttle: float, cfg: CompanionConfig) -> None:
    """LandingEnv's checks, and the in-process SITL's (its own camera)."""
    if n_envs < 1:
        raise ConfigError(f"n_envs must be at least 1, got {n_envs}")
    if action_dims not in (2, 3, 4):
        raise ConfigError(f"action_dims must be 2 (pitch, roll), 3 (+ throttle) or 4 (+ yaw), got {action_dims}")
    if not -1.0 <= descent_throttle <= 0.0:
        raise ConfigError(f"descent_throttle is a stick value in [-1, 0] (down), got {descent_throttle}")
    if cfg.perception.camera.strip() != "auto":
        raise ConfigError(f"the batched env sees the SITL's camera (camera = \"auto\"), not {cfg.perception.camera!r}")


def batched_factory(n_envs: int, action_dims: int, cfg: CompanionConfig, config_path: Path | None,
                    descent_throttle: float = DESCENT_THROTTLE) -> Callable[[], VecEnv]:
    """A picklable recipe for one batch (a worker process builds its own)."""
    return partial(BatchedLandingEnv, n_envs, action_dims, cfg, descent_throttle=descent_throttle,
                   config_path=config_path)


def batched_workers(n_envs: int, workers: int, action_dims: int, cfg: CompanionConfig,
                    config_path: Path | None = None, descent_throttle: float = DESCENT_THROTTLE) -> VecEnv:
    """``n_envs`` envs in ``workers`` processes, each a :class:`BatchedLandingEnv` of its share
    (sizes differing by at most one), behind the grouped vec env's pipes: one message per batch
    and step. One worker: the batch in this process, no pipe at all."""
    sizes = group_sizes(n_envs, workers)
    if workers == 1:
        return BatchedLandingEnv(n_envs, action_dims, cfg, descent_throttle=descent_throttle, config_path=config_path)
    makers: Sequence[Callable[[], VecEnv]] = [batched_factory(size, action_dims, cfg, config_path, descent_throttle)
                                              for size in sizes]
    return GroupedSubprocVecEnv.of_groups(makers, sizes)
