"""The grid's training runs as Ray tasks: on a cluster, or on a local Ray instance.

``run_grid(..., backend="ray", address=...)`` hands its training runs to :func:`run_on_ray`,
the counterpart of the runner's process pool: each run is one task that does what
``run_training_safely(setup, run, out_dir, run_fn)`` does in the pool; it reserves one CPU (a
trial and its SITL keep about one core busy) and starts its own SITL on its worker's
loopback; at most ``workers`` tasks are in flight; each run's results come back to the driver as it finishes
(completion order), and the driver appends them to ``results.jsonl``. A task whose worker
dies (killed, out of memory, a lost node) gives ``error`` results for its trials, as a run
that raised does, so a resumed grid runs it again.

Ctrl-C (or SIGTERM, which ``col`` turns into one) in the driver force-cancels every task
still pending or running (the worker process exits; the SITL dies with it), records nothing
of them, shuts down a local instance this call started, and re-raises.

``address`` None starts a local instance of ``workers`` CPUs whose servers listen on
127.0.0.1 only, with its session files in a short-lived folder under ``/tmp``; otherwise the
driver connects to the cluster at ``address`` (``HOST:6379`` of ``ray start --head``), whose
nodes must have the project installed and ``out_dir`` mounted at the same absolute path
(docs/experiment.md, "Running on a cluster"). Ray is an optional dependency
(``pip install '.[cluster]'``), imported only here and only when used.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import logging
import os
import shutil
import signal
import sys
import tempfile
import threading
import time
from collections import deque
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from companion.errors import ConfigError
from companion.experiment.grid import ExperimentSetup, TrainingRun
from companion.experiment.results import TrialResult
from companion.experiment.tasks import CONFIG_COPY, RunFn, init_worker, run_training_safely

log = logging.getLogger(__name__)

LOCAL_ENV = {
    # Ray's servers bind 127.0.0.1, not the machine's outward address on every interface
    "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0",
    # Ray 2.60 turns on token authentication for a new local instance (a token file in ~/.ray)
    "RAY_AUTH_MODE": "disabled",
    "RAY_USAGE_STATS_ENABLED": "0",
}
"""Environment of a local instance: read when ``ray`` is imported and by the processes it starts."""
OBJECT_STORE_BYTES = 75 * 2**20
"""Ray's minimum object store (its default is 30 % of RAM); tasks return a few small results."""
WAIT_S = 1.0
"""The driver wakes up at least this often, so Ctrl-C is seen while every task is running."""
CANCEL_WAIT_S = 10.0
"""How long an interrupted driver waits for force-cancelled tasks to end."""


def run_on_ray(setup: ExperimentSetup, runs: list[TrainingRun], out_dir: Path, workers: int,
               run_fn: RunFn, address: str | None) -> Iterator[list[TrialResult]]:
    """Each run's results as it finishes, from Ray tasks (at most ``workers`` at once)."""
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    if not ray_installed():
        raise ConfigError("--backend ray needs Ray, an optional dependency: pip install '.[cluster]' "
                          "(or pip install 'ray>=2.9') in the project's environment, on every node")
    if not runs:
        return
    setup = _portable(setup, out_dir)
    with ray_instance(workers, address) as ray:
        yield from _run_tasks(ray, setup, runs, out_dir, workers, run_fn)


def ray_installed() -> bool:
    """Whether the optional dependency is there (without importing it)."""
    return importlib.util.find_spec("ray") is not None


def _portable(setup: ExperimentSetup, out_dir: Path) -> ExperimentSetup:
    """The setup with its experiment file at a path every worker can read.

    Workers run in another directory (a relative path breaks) and on other machines; the
    driver has copied the file into ``out_dir`` (``config.toml``), which every node mounts.
    The copy has the same content, and the path is not part of the fingerprint or a result.
    """
    if setup.config_path is None:
        return setup
    copy = out_dir / CONFIG_COPY
    path = copy if copy.is_file() else setup.config_path.resolve()
    return dataclasses.replace(setup, config_path=path)


def _task(setup: ExperimentSetup, run: TrainingRun, out_dir: Path, run_fn: RunFn) -> list[TrialResult]:
    """One training run in a Ray worker, as in a process of the pool."""
    init_worker()
    return run_training_safely(setup, run, out_dir, run_fn)


def _run_tasks(ray: Any, setup: ExperimentSetup, runs: list[TrainingRun], out_dir: Path, workers: int,
               run_fn: RunFn) -> Iterator[list[TrialResult]]:
    # max_retries=0: a run whose worker died is reported (and rerun on resume), not silently
    # retried; a force-cancelled task is never retried anyway
    task = ray.remote(num_cpus=1, max_retries=0)(_task)
    setup_ref = ray.put(setup)  # serialised once for all tasks
    todo = deque(runs)
    running: dict[Any, TrainingRun] = {}  # ObjectRef -> its run
    try:
        while todo or running:
            while todo and len(running) < workers:
                run = todo.popleft()
                running[task.remote(setup_ref, run, out_dir, run_fn)] = run
            ready, _ = ray.wait(list(running), num_returns=1, timeout=WAIT_S)
            for ref in ready:
                yield _results(ray, ref, setup, running.pop(ref))
    except BaseException:  # Ctrl-C, SIGTERM, or the consumer stopped (GeneratorExit)
        _cancel(ray, list(running))
        raise


def _results(ray: Any, ref: Any, setup: ExperimentSetup, run: TrainingRun) -> list[TrialResult]:
    """A finished task's results; a task that died gives error results for its trials."""
    try:
        results: list[TrialResult] = ray.get(ref)
    except ray.exceptions.RayError as exc:  # WorkerCrashedError, OutOfMemoryError, NodeDiedError, ...
        error = f"{type(exc).__name__}: {exc}"[:2000]
        results = [TrialResult(trial=t, fingerprint=setup.fingerprint(), status="error", error=error)
                   for t in run.trials]
    for result in results:
        if result.status == "error":  # the worker's own log stays on its node
            log.warning("training run %s failed on Ray: %s", run.key, result.error)
            break
    return results


def _cancel(ray: Any, refs: list[Any]) -> None:
    """Force-cancel tasks still pending or running, then wait (bounded) until they end.

    Without force a task blocked in a subprocess wait (its SITL) is not interrupted.
    """
    if not refs:
        return
    for ref in refs:
        try:
            ray.cancel(ref, force=True)
        except Exception as exc:  # finished meanwhile, or the instance is going away
            log.debug("cancelling %s: %r", ref, exc)
    t0 = time.monotonic()
    pending = refs
    while pending and (left := t0 + CANCEL_WAIT_S - time.monotonic()) > 0:
        try:
            _, pending = ray.wait(pending, num_returns=len(pending), timeout=left)
        except Exception as exc:  # the local instance died with the interrupt
            log.info("waiting for cancelled Ray tasks: %r", exc)
            return
    if pending:
        log.warning("%d Ray tasks did not end within %.0f s of being cancelled", len(pending), CANCEL_WAIT_S)
    else:
        log.info("cancelled %d Ray tasks in %.1f s", len(refs), time.monotonic() - t0)


@contextmanager
def ray_instance(workers: int, address: str | None) -> Iterator[Any]:
    """The ``ray`` module, initialised: a local instance of ``workers`` CPUs, or the cluster at
    ``address``; shut down (a cluster: disconnected) on the way out. A Ray already initialised
    in this process is used as it is and left running."""
    saved_env = {k: os.environ.get(k) for k in LOCAL_ENV}
    if address is None:
        os.environ.update(LOCAL_ENV)
    import ray

    if ray.is_initialized():
        log.info("using the Ray instance this process is already connected to")
        _restore_env(saved_env)
        yield ray
        return
    temp_dir = None
    constants: Any = sys.modules.get("ray._private.ray_constants")
    loopback_patched = False
    sigterm = signal.getsignal(signal.SIGTERM)
    try:
        if address is None:
            if constants is not None and getattr(constants, "ENABLE_RAY_CLUSTER", False):
                # ray was imported before LOCAL_ENV was set: the constant was read already
                constants.ENABLE_RAY_CLUSTER = False
                loopback_patched = True
            # Ray's session files (logs, sockets) go here, not to /tmp/ray; short, as unix
            # socket paths are limited to 107 bytes
            temp_dir = tempfile.mkdtemp(prefix="colray-", dir="/tmp" if os.path.isdir("/tmp") else None)
            kwargs: dict[str, Any] = {
                "num_cpus": workers, "include_dashboard": False, "object_store_memory": OBJECT_STORE_BYTES,
                "_temp_dir": temp_dir}
        else:  # a cluster refuses (or hangs on) the resource and session options
            kwargs = {"address": address}
        t0 = time.monotonic()
        try:
            _init(ray, kwargs, local=address is None)
        except Exception as exc:
            if address is None:
                raise
            raise ConfigError(
                f"could not connect to the Ray cluster at {address} ({type(exc).__name__}: {exc}); give "
                "--address HOST:PORT of `ray start --head` (6379 by default); a cluster with token "
                "authentication (Ray 2.60) also needs RAY_AUTH_MODE=token and its token (RAY_AUTH_TOKEN, "
                "or ~/.ray/auth_token) in this command's environment") from exc
        finally:
            _restore_sigterm(sigterm)  # ray.init replaces the driver's handler
            temp_dir = kwargs.get("_temp_dir", temp_dir)  # a second start has a folder of its own
        log.info("Ray %s in %.1f s: %s", "connected" if address else "local instance started",
                 time.monotonic() - t0, ray.cluster_resources())
        yield ray
    finally:
        t0 = time.monotonic()
        ray.shutdown()  # a local instance stops; a cluster is only disconnected from
        _restore_sigterm(sigterm)
        log.info("Ray shut down in %.1f s", time.monotonic() - t0)
        if loopback_patched:
            constants.ENABLE_RAY_CLUSTER = True
        if temp_dir is not None:
            shutil.rmtree(temp_dir, ignore_errors=True)
        _restore_env(saved_env)


LOCAL_START_ATTEMPTS = 2
"""Ray waits a fixed 30 s for its raylet to register; on a loaded machine a first start can miss that."""


def _init(ray: Any, kwargs: dict[str, Any], local: bool) -> None:
    """``ray.init``; a local instance that timed out while starting is stopped (what it started is
    killed: Ray does not) and started once more in a fresh session folder."""
    for attempt in range(1, (LOCAL_START_ATTEMPTS if local else 1) + 1):
        try:
            ray.init(log_to_driver=False, configure_logging=False, **kwargs)
            return
        except Exception as exc:
            if not local or attempt == LOCAL_START_ATTEMPTS or "timed out" not in str(exc):
                if local:
                    _kill_ray_descendants()
                raise
            log.warning("the local Ray instance did not start (%s); starting it again", exc)
            _kill_ray_descendants()
            ray.shutdown()
            shutil.rmtree(kwargs["_temp_dir"], ignore_errors=True)
            kwargs["_temp_dir"] = tempfile.mkdtemp(prefix="colray-", dir=os.path.dirname(kwargs["_temp_dir"]))


def _kill_ray_descendants() -> None:
    """SIGKILL this process's descendants that run Ray's code (its servers, raylet, workers)."""
    for pid in ray_descendants(os.getpid()):
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass


def process_children() -> dict[int, list[int]]:
    """Every process's children, from /proc (Linux; empty elsewhere)."""
    children: dict[int, list[int]] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            ppid = int(stat.read_text().rsplit(")", 1)[1].split()[1])
        except (OSError, IndexError, ValueError):
            continue
        children.setdefault(ppid, []).append(int(stat.parent.name))
    return children


def ray_descendants(root: int) -> list[int]:
    """Descendants of ``root`` whose command line names Ray's package (Linux /proc; [] elsewhere)."""
    children = process_children()
    found, todo = [], list(children.get(root, []))
    while todo:
        pid = todo.pop()
        todo += children.get(pid, [])
        try:
            cmdline = Path(f"/proc/{pid}/cmdline").read_bytes()
        except OSError:
            continue
        if b"/ray/" in cmdline:
            found.append(pid)
    return found


def _restore_sigterm(handler: Any) -> None:
    if handler is not None and threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, handler)


def _restore_env(saved: dict[str, str | None]) -> None:
    for key, value in saved.items():
        if value is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = value
