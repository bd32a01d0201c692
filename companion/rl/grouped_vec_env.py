"""Many envs in few worker processes: each worker steps a group of envs per message.

stable-baselines3's ``SubprocVecEnv`` puts one env in each process and hands every step over a
pipe: two messages and two wake-ups of another process per env step. On this task that
hand-over cost about as much CPU as the env step itself (docs/baselines.md, "Speed of the
env"). Here ``n_workers`` processes each hold a group of the envs in a ``DummyVecEnv`` and step
all of them on one message, so the hand-over is paid once per group. What each env sees
(seeds, actions, auto-reset, ``terminal_observation``) is the ``DummyVecEnv``'s, so a grouped
vec env gives the same observations as a ``DummyVecEnv`` of the same envs (tests/rl).
"""

from __future__ import annotations

import multiprocessing as mp
from collections.abc import Callable, Sequence
from functools import partial
from multiprocessing.connection import Connection
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv
from stable_baselines3.common.vec_env.base_vec_env import (
    CloudpickleWrapper,
    VecEnvIndices,
    VecEnvObs,
    VecEnvStepReturn,
)

from companion.errors import ConfigError


def _serve(remote: Connection, parent_remote: Connection, maker: CloudpickleWrapper) -> None:
    """A worker: builds its group of envs and says whether it could (None, or the exception),
    then answers the parent's commands until "close"."""
    parent_remote.close()
    try:
        group: VecEnv = maker.var()
    except Exception as exc:  # noqa: BLE001 - the parent raises it
        _send_error(remote, exc)
        remote.close()
        return
    remote.send(None)
    try:
        while True:
            try:
                cmd, data = remote.recv()
            except EOFError:  # the parent is gone
                return
            if cmd == "close":
                remote.send(None)
                return
            try:
                answer = _answer(group, cmd, data)
            except Exception as exc:  # noqa: BLE001 - the parent raises it: the worker stays up to close
                _send_error(remote, exc)
                continue
            remote.send(answer)
    finally:
        group.close()
        remote.close()


def _send_error(remote: Connection, exc: Exception) -> None:
    """Hand an exception to the parent; one that cannot be pickled goes as its text."""
    try:
        remote.send(exc)
    except Exception:  # noqa: BLE001 - e.g. an exception holding a socket
        remote.send(RuntimeError(f"{type(exc).__name__}: {exc}"))


def _answer(group: VecEnv, cmd: str, data: Any) -> Any:
    """What a worker answers to one command (the envs' own seeds, auto-reset and
    ``terminal_observation`` are the group's: a ``DummyVecEnv``'s, or a batched env's, which
    behaves alike)."""
    if cmd == "step":
        group.step_async(data)
        return (*group.step_wait(), group.reset_infos)
    if cmd == "reset":
        group._seeds, group._options = list(data[0]), list(data[1])
        return group.reset(), group.reset_infos
    if cmd == "spaces":
        return group.observation_space, group.action_space
    if cmd == "get_attr":
        return group.get_attr(data[0], data[1])
    if cmd == "set_attr":
        return group.set_attr(data[0], data[1], data[2])
    if cmd == "env_method":
        return group.env_method(data[0], *data[1], indices=data[2], **data[3])
    if cmd == "is_wrapped":
        return group.env_is_wrapped(data[0], data[1])
    raise NotImplementedError(f"unknown command {cmd!r}")


def group_sizes(n_envs: int, n_workers: int) -> list[int]:
    """``n_envs`` envs in ``n_workers`` groups, in order, sizes differing by at most one (7 in 3:
    3, 2, 2)."""
    if n_envs < 1:
        raise ConfigError("a grouped vec env needs at least one env")
    if not 1 <= n_workers <= n_envs:
        raise ConfigError(f"n_workers must be between 1 and the number of envs ({n_envs}), got {n_workers}")
    base, extra = divmod(n_envs, n_workers)
    return [base + (1 if k < extra else 0) for k in range(n_workers)]


class GroupedSubprocVecEnv(VecEnv):
    """``len(factories)`` envs in ``n_workers`` processes, in order, the group sizes differing by
    at most one (7 envs in 3 workers: 3, 2, 2), each group a ``DummyVecEnv``; or, with
    :meth:`of_groups`, any vec envs, one per worker (the batched env's batches). If any worker
    cannot build its envs, every worker is stopped and its exception raised here."""

    def __init__(self, factories: Sequence[Callable[[], gym.Env[Any, Any]]], n_workers: int,
                 start_method: str = "forkserver") -> None:
        sizes = group_sizes(len(factories), n_workers)
        starts = np.cumsum([0, *sizes]).tolist()
        makers = [partial(DummyVecEnv, list(factories[a:b])) for a, b in zip(starts[:-1], starts[1:], strict=True)]
        self._start(makers, sizes, start_method)

    @classmethod
    def of_groups(cls, makers: Sequence[Callable[[], VecEnv]], sizes: Sequence[int],
                  start_method: str = "forkserver") -> GroupedSubprocVecEnv:
        """One worker per maker, each holding the vec env it makes (of ``sizes[k]`` envs)."""
        if not makers or len(makers) != len(sizes) or min(sizes) < 1:
            raise ConfigError(f"a grouped vec env needs one size (at least 1) per group, got {list(sizes)}")
        venv = cls.__new__(cls)
        venv._start(makers, sizes, start_method)
        return venv

    def _start(self, makers: Sequence[Callable[[], VecEnv]], sizes: Sequence[int], start_method: str) -> None:
        starts = np.cumsum([0, *sizes]).tolist()
        self._slices = [slice(a, b) for a, b in zip(starts[:-1], starts[1:], strict=True)]
        ctx: Any = mp.get_context(start_method)  # typeshed's BaseContext lacks Process and Pipe
        self.remotes: list[Connection] = []
        self.processes: list[Any] = []
        for maker in makers:
            remote, work_remote = ctx.Pipe()
            proc = ctx.Process(target=_serve, args=(work_remote, remote, CloudpickleWrapper(maker)), daemon=True)
            proc.start()
            work_remote.close()
            self.remotes.append(remote)
            self.processes.append(proc)
        self.closed = False
        self.waiting = False
        try:
            for remote in self.remotes:
                self._recv(remote)  # None once the worker's envs are built
        except BaseException:
            self._stop_workers(wait_s=0.0)
            raise
        self.remotes[0].send(("spaces", None))
        observation_space, action_space = self._recv(self.remotes[0])
        super().__init__(starts[-1], observation_space, action_space)

    def _stop_workers(self, wait_s: float) -> None:
        """Wait up to ``wait_s`` for each worker to exit, terminate any still running."""
        for proc in self.processes:
            proc.join(timeout=wait_s)
            if proc.is_alive():
                proc.terminate()
                proc.join(timeout=30)
        for remote in self.remotes:
            remote.close()
        self.closed = True

    @staticmethod
    def _recv(remote: Connection) -> Any:
        answer = remote.recv()
        if isinstance(answer, Exception):
            raise answer
        return answer

    def _local(self, indices: VecEnvIndices) -> list[tuple[Connection, list[int]]]:
        """Each worker holding some of ``indices``, with those envs' indices within its group."""
        wanted = set(self._get_indices(indices))
        out = []
        for remote, part in zip(self.remotes, self._slices, strict=True):
            local = [i - part.start for i in range(part.start, part.stop) if i in wanted]
            if local:
                out.append((remote, local))
        return out

    def step_async(self, actions: np.ndarray) -> None:
        for remote, part in zip(self.remotes, self._slices, strict=True):
            remote.send(("step", actions[part]))
        self.waiting = True

    def step_wait(self) -> VecEnvStepReturn:
        answers = [self._recv(remote) for remote in self.remotes]
        self.waiting = False
        obs = np.concatenate([a[0] for a in answers])
        rewards = np.concatenate([a[1] for a in answers])
        dones = np.concatenate([a[2] for a in answers])
        infos = [info for a in answers for info in a[3]]
        self.reset_infos = [info for a in answers for info in a[4]]
        return obs, rewards, dones, infos

    def reset(self) -> VecEnvObs:
        for remote, part in zip(self.remotes, self._slices, strict=True):
            remote.send(("reset", (self._seeds[part], self._options[part])))
        answers = [self._recv(remote) for remote in self.remotes]
        self.reset_infos = [info for a in answers for info in a[1]]
        self._reset_seeds()
        self._reset_options()
        return np.concatenate([a[0] for a in answers])

    def close(self) -> None:
        if self.closed:
            return
        if self.waiting:
            for remote in self.remotes:
                remote.recv()
        for remote in self.remotes:
            try:
                remote.send(("close", None))
                remote.recv()
            except (EOFError, BrokenPipeError, ConnectionResetError):
                pass  # that worker is already gone
        self._stop_workers(wait_s=30.0)

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        parts = self._local(indices)
        for remote, local in parts:
            remote.send(("get_attr", (attr_name, local)))
        return [value for remote, _ in parts for value in self._recv(remote)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        parts = self._local(indices)
        for remote, local in parts:
            remote.send(("set_attr", (attr_name, value, local)))
        for remote, _ in parts:
            self._recv(remote)

    def env_method(self, method_name: str, *method_args: Any, indices: VecEnvIndices = None,
                   **method_kwargs: Any) -> list[Any]:
        parts = self._local(indices)
        for remote, local in parts:
            remote.send(("env_method", (method_name, method_args, local, method_kwargs)))
        return [value for remote, _ in parts for value in self._recv(remote)]

    def env_is_wrapped(self, wrapper_class: type[gym.Wrapper[Any, Any, Any, Any]],
                       indices: VecEnvIndices = None) -> list[bool]:
        parts = self._local(indices)
        for remote, local in parts:
            remote.send(("is_wrapped", (wrapper_class, local)))
        return [value for remote, _ in parts for value in self._recv(remote)]
