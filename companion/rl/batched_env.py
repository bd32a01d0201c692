"""The landing task for N envs in one process: the batched, session-free vec env.

:class:`BatchedLandingEnv` flies the episodes of ``LandingEnv(inprocess=True)``, N at a time,
without the objects that carry them there (MAVLink messages, link, session, observer). Each env
is a :class:`~companion.rl.landing_lane.LandingLane`: the SITL's own vehicle, scheduler and
renderer driven directly, with the session's home frame, geofence and episode start (and what
``LandingEnv`` flies before its first episode, so its simulation clock, from which episode starts
are taken, is the same too). The episodes are flown by the batched episode core
(:class:`~companion.control.lanes.EpisodeLanes`): the session's setpoint and observation
arithmetic on stacks of rows (each row as that env's own, bit for bit), the one outcome rule and
the one scoring rule (:mod:`companion.control.outcome`). This module adapts the core to
stable-baselines3: the actions become sticks (:func:`~companion.rl.landing_task.stick_rows`), the
rewards and infos are ``LandingEnv``'s (:func:`~companion.rl.landing_task.outcome_info`).

So for the same seeds and actions it flies the same episodes as ``LandingEnv(inprocess=True)``:
the same observations, rewards, terminations, outcomes and touchdowns
(``tests/rl/test_batched_env.py`` checks them step by step). What it leaves out changes no
episode: the MAVLink framing, the ACKs and STATUSTEXTs, the wall-clock times the link keeps, the
"link lost" outcome (a frame cannot be late in one thread), the images of frames nobody observes,
and a ``ColError`` for a step after the end (a vec env resets instead). A lane that leaves the
geofence is told to hold, as the session tells its vehicle, before its reset.

As a stable-baselines3 ``VecEnv`` it behaves like ``DummyVecEnv`` of ``LandingEnv``s: ``seed(s)``
then ``reset()`` starts env ``k`` from ``s + k``; an env that is done is reset at once, with its
next seed, its last observation in ``info["terminal_observation"]``. Several processes, each with
a batch, are :func:`batched_workers` (one per core).
"""

from __future__ import annotations

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
from companion.control.lanes import EpisodeLanes
from companion.errors import ColError, ConfigError
from companion.inprocess import sitl_config_for
from companion.rl.grouped_vec_env import GroupedSubprocVecEnv, group_sizes
from companion.rl.landing_lane import open_lanes
from companion.rl.landing_task import (
    ACTION_AXES,
    DESCENT_THROTTLE,
    check_task,
    observation_space,
    outcome_info,
    stick_rows,
)


class BatchedLandingEnv(VecEnv):
    """``n_envs`` landing envs stepped together in this process (module docstring): the episodes
    of ``n_envs`` ``LandingEnv(inprocess=True)`` in a ``DummyVecEnv``, without their session,
    link and telemetry messages."""

    def __init__(self, n_envs: int, action_dims: int = 2, cfg: CompanionConfig | None = None, *,
                 descent_throttle: float = DESCENT_THROTTLE, config_path: Path | None = None) -> None:
        cfg = cfg or CompanionConfig()
        if n_envs < 1:
            raise ConfigError(f"n_envs must be at least 1, got {n_envs}")
        check_task(action_dims, descent_throttle)
        if cfg.perception.camera.strip() != "auto":
            raise ConfigError(f"the batched env sees the SITL's camera (camera = \"auto\"), not {cfg.perception.camera!r}")
        self.cfg, self.action_dims, self.descent_throttle = cfg, action_dims, descent_throttle
        sitl_cfg = sitl_config_for(cfg, RunOptions(config_path=config_path))
        self._stack, self.lanes = open_lanes(cfg, sitl_cfg, n_envs, action_dims, descent_throttle)
        self.core = EpisodeLanes(cfg, self.lanes)  # the position from home, as the session observes it
        self._rows = list(range(n_envs))
        self._sticks = np.zeros((n_envs, 4))
        self.closed = False
        action_space = gym.spaces.Box(-1.0, 1.0, (action_dims,), dtype=np.float32)
        super().__init__(n_envs, observation_space(), action_space)

    # ----- stable-baselines3's VecEnv --------------------------------------------------------
    def reset(self) -> VecEnvObs:
        """Every env from its seed (``seed(s)``: ``s + k``), else its next one, as ``DummyVecEnv``."""
        for i in self._rows:
            self.reset_infos[i] = self._begin(i, self._seeds[i])
        obs, _ = self.core.observe(self._rows)
        self._reset_seeds()
        self._reset_options()
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        """Checked and turned into sticks now, so a bad action fails the call that gave it."""
        if self.closed:
            raise ColError("the batched env is closed; make a new one")
        a = np.asarray(actions, dtype=np.float64)
        if a.ndim == 0 or a.shape[0] != self.num_envs or a[0].size != self.action_dims:
            raise ValueError(f"expected actions of shape ({self.num_envs}, {self.action_dims}): one row of "
                             f"{ACTION_AXES[:self.action_dims]} per env, got shape {a.shape}")
        self._sticks = stick_rows(a.reshape(self.num_envs, self.action_dims), self.descent_throttle)

    def step_wait(self) -> VecEnvStepReturn:
        """Each env's step as ``LandingEnv.step``: the frame, its observation, its judgement."""
        core = self.core
        core.fly(self._sticks)
        obs, _ = core.observe(self._rows)  # an unusable one repeats the last good one, as LandingEnv's
        rewards = np.zeros(self.num_envs, dtype=np.float32)
        dones = np.zeros(self.num_envs, dtype=bool)
        infos: list[dict[str, Any]] = []
        for i, outcome in enumerate(core.judge(self._rows)):
            info, rewards[i] = outcome_info(self.lanes[i].seed, core.steps[i], outcome, core.score(i, outcome or ""))
            dones[i] = outcome is not None
            info["TimeLimit.truncated"] = outcome == outcome_rule.TIMEOUT
            infos.append(info)
        done = np.flatnonzero(dones).tolist()
        for i in done:  # its last observation into its info, then its next episode
            infos[i]["terminal_observation"] = obs[i].copy()
            self.lanes[i].ended_truth = self.lanes[i].ground_truth()
            self.reset_infos[i] = self._begin(i, None)
        if done:
            obs[done] = core.observe(done)[0]
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

    def _begin(self, i: int, seed: int | None) -> dict[str, Any]:
        """``LandingEnv.reset(seed=seed)`` for env ``i``, but for the observation: its reset info."""
        lane = self.lanes[i]
        if seed is not None:
            seeding.np_random(seed)  # the same check of the seed as gymnasium's Env.reset
        start = lane.next_seed if seed is None else int(seed)
        lane.next_seed, lane.seed = start + 1, start
        self.core.begin(i, start)
        return {"seed": start}


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
