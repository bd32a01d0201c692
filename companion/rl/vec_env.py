"""Several landing envs at once, for PPO and the speed bench.

Each env is a :class:`~companion.rl.gym_env.LandingEnv` flying its own SITL in-process (no
sockets: about half the CPU per step of the MAVLink path, the same episodes). With more than
one env, each runs in a worker process (stable-baselines3's ``SubprocVecEnv``, ``forkserver``):
the SITL is single-threaded Python, so processes are how it uses more than one core. Or, with
``batched``, the same episodes from :class:`~companion.rl.batched_env.BatchedLandingEnv`, which
steps its envs together without their session, link and telemetry messages.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import gymnasium as gym
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecEnv

from companion.config import CompanionConfig
from companion.errors import ConfigError
from companion.rl.batched_env import batched_workers
from companion.rl.grouped_vec_env import GroupedSubprocVecEnv
from companion.rl.gym_env import DESCENT_THROTTLE, LandingEnv


def env_factory(action_dims: int, cfg: CompanionConfig, config_path: Path | None, *, inprocess: bool = True,
                descent_throttle: float = DESCENT_THROTTLE) -> Callable[[], gym.Env[Any, Any]]:
    """A picklable recipe for one env (a worker process builds its own SITL)."""

    def make() -> gym.Env[Any, Any]:
        return LandingEnv(action_dims, cfg, config_path=config_path, inprocess=inprocess,
                          descent_throttle=descent_throttle)

    return make


def make_vec_env(action_dims: int, cfg: CompanionConfig, n_envs: int = 1, config_path: Path | None = None,
                 *, inprocess: bool = True, subprocess: bool | None = None, workers: int | None = None,
                 batched: bool = False) -> VecEnv:
    """``n_envs`` envs; in worker processes when ``subprocess`` (default: when ``n_envs > 1``),
    one per env, or ``workers`` processes each stepping a group of envs per message
    (:class:`~companion.rl.grouped_vec_env.GroupedSubprocVecEnv`: the pipe's hand-over paid once
    per group, not once per env). ``batched``: the same episodes from the batched, session-free
    env (:mod:`companion.rl.batched_env`), in this process or, with ``workers``, in that many
    processes each stepping its share of the envs.

    stable-baselines3 seeds env ``k`` with ``seed + k`` on the first reset; later resets continue
    each env's own seeds (``LandingEnv.reset`` without a seed), so starts of different envs can
    repeat: they are training starts, never the held-out ones.
    """
    if n_envs < 1:
        raise ConfigError(f"n_envs must be at least 1, got {n_envs}")
    if workers is not None and not 1 <= workers <= n_envs:
        raise ConfigError(f"workers must be between 1 and the number of envs ({n_envs}), got {workers}")
    if batched:
        if not inprocess:
            raise ConfigError("the batched env flies its SITLs in its own process; it cannot fly over MAVLink")
        return batched_workers(n_envs, workers or 1, action_dims, cfg, config_path)
    factories = [env_factory(action_dims, cfg, config_path, inprocess=inprocess) for _ in range(n_envs)]
    if workers is not None and workers < n_envs:
        return GroupedSubprocVecEnv(factories, workers)
    if subprocess if subprocess is not None else n_envs > 1:
        return SubprocVecEnv(factories, start_method="forkserver")
    return DummyVecEnv(factories)
