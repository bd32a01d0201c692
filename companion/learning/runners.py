"""How the learner's loop is run beside the control loop.

:class:`BudgetedLearner` runs k updates per control step (reproducible: training is tied to
control steps, never to the machine's speed); :class:`LearnerThread` trains continuously in
live flight; :func:`make_runner` picks one, or the child process of
:mod:`companion.learning.learner_process`, from the config's ``mode``.
"""

from __future__ import annotations

import logging
import math
import os
import sys
import threading
import time
from collections.abc import Callable

from companion.learning.learner import Learner, LearnerState
from companion.learning.learner_process import LearnerProcess
from companion.learning.snapshot import PolicySnapshot
from companion.learning.trainer import limit_torch_threads

log = logging.getLogger(__name__)


class BudgetedLearner:
    """Runs ``updates_per_step`` updates per control step: results do not depend on CPU speed."""

    def __init__(self, learner: Learner, updates_per_step: int | None = None) -> None:
        self.learner = learner
        self.updates_per_step = (
            learner.config.updates_per_step if updates_per_step is None else updates_per_step
        )
        if self.updates_per_step < 1:
            raise ValueError("updates_per_step must be >= 1")

    def on_control_step(self, tick_start_s: float | None = None) -> PolicySnapshot:
        """Train for this step's budget (if there is work) and return the snapshot to fly.

        ``tick_start_s`` is accepted for the runners' common signature and not needed here.
        """
        if self.learner.has_work:
            self.learner.train_until_converged(budget=self.updates_per_step)
        return self.learner.latest_snapshot

    def between_episodes(self) -> int:
        """Train while the vehicle is repositioned: ``between_episode_updates`` at most (the
        round still ends at convergence or ``max_updates``); the number of updates run. With
        ``holdout_stop``: until the held-out loss stops improving, at most that many
        (:meth:`Learner.train_to_holdout_stop`), whenever the dataset changed.

        Without it the last episode's samples get only the updates of its final control steps
        before the checkpoint is written.
        """
        budget = self.learner.config.between_episode_updates
        if self.learner.config.holdout_stop:  # to the held-out loss's stopping rule instead
            if budget == 0 or not self.learner.has_unsettled_samples:
                return 0
            result = self.learner.train_to_holdout_stop(budget)
            log.info("between episodes: %s", result)
            return result.updates
        if budget == 0 or not self.learner.has_work:
            return 0
        return self.learner.train_until_converged(budget=budget).updates

    @property
    def latest_snapshot(self) -> PolicySnapshot:
        return self.learner.latest_snapshot

    @property
    def error(self) -> BaseException | None:
        return None

    def start(self) -> None:
        """Nothing runs in the background in budgeted mode."""

    def stop(self, timeout_s: float = 5.0) -> None:
        """Nothing to stop in budgeted mode."""


class ControlTickGuard:
    """Keeps the learner off the GIL around each expected control tick.

    The control loop reports its ticks (``tick()``); from them the guard learns the period.
    ``pause()``, called by the learner between updates, blocks (without holding the GIL) from
    ``guard_s`` before the next expected tick until that tick is reported, or until
    ``guard_s`` after it at the latest, so a control loop that stops ticking never stalls
    learning. Without reported ticks it never pauses.

    ``clock`` (seconds, ``time.perf_counter`` by default) is the one time source, so that tests
    can check the windows on a clock of their own instead of a loaded machine's sleeps.
    """

    def __init__(self, guard_s: float, period_s: float | None = None,
                 clock: Callable[[], float] = time.perf_counter) -> None:
        self.guard_s = guard_s
        self.period_s = period_s
        self._clock = clock
        self._fixed_period = period_s is not None
        self._cond = threading.Condition(threading.Lock())
        self._ticks = 0
        self._last_tick_s: float | None = None

    def tick(self, started_s: float | None = None) -> None:
        """Called by the control loop once per tick (cheap: a lock and a notify).

        ``started_s``: the clock's time when the tick began, if this is called later in the
        tick; the window protects the start of the next tick.
        """
        now = self._clock() if started_s is None else started_s
        with self._cond:
            if self._last_tick_s is not None and not self._fixed_period:
                interval = now - self._last_tick_s
                if interval < 1.0:  # a pause between episodes is not a period
                    self.period_s = interval if self.period_s is None else (
                        0.8 * self.period_s + 0.2 * interval)
            self._last_tick_s = now
            self._ticks += 1
            self._cond.notify_all()

    def wait_limit_s(self, now: float) -> float:
        """How long :meth:`pause` at clock time ``now`` may block: until ``guard_s`` after the
        expected tick whose window ``[tick - guard_s, tick + guard_s)`` holds ``now``; 0 outside."""
        last, period = self._last_tick_s, self.period_s
        if self.guard_s <= 0 or last is None or not period:
            return 0.0
        # the first expected tick whose window has not passed
        next_tick = last + period * max(1, math.floor((now - self.guard_s - last) / period) + 1)
        if not next_tick - self.guard_s <= now < next_tick + self.guard_s:
            return 0.0
        return next_tick + self.guard_s - now

    def pause(self) -> float:
        """Block while a control tick is imminent, until it is reported or the window ends;
        returns the clock seconds spent waiting."""
        now = self._clock()
        limit_s = self.wait_limit_s(now)
        if limit_s <= 0.0:
            return 0.0
        with self._cond:
            seen = self._ticks
            self._cond.wait_for(lambda: self._ticks != seen, timeout=limit_s)
        return self._clock() - now


class LearnerThread:
    """Runs the paper's loop continuously in a daemon thread (live flight).

    The control loop calls ``on_control_step()`` once per tick for the snapshot to fly (one
    attribute load). A failure ends the thread with state FAILED, is logged and kept in
    ``error``; the last good snapshot stays.

    So that control keeps its core and its timing, the thread limits torch's threads, lowers
    its own OS priority (``thread_nice``), steps aside just before each expected control tick
    (:class:`ControlTickGuard`, ``control_guard_s``) and, while it runs, shortens the GIL
    switch interval (``gil_switch_interval_s``; restored by ``stop``) for anything else.
    """

    def __init__(self, learner: Learner, *, control_period_s: float | None = None,
                 idle_wait_s: float = 0.05) -> None:
        self.learner = learner
        self.idle_wait_s = idle_wait_s
        self.guard = ControlTickGuard(learner.config.control_guard_s, control_period_s)
        self._state = LearnerState.NEW
        self._error: BaseException | None = None
        self._stop = threading.Event()
        self._saved_switch_interval_s: float | None = None
        self._thread = threading.Thread(target=self._run, name="col-learner", daemon=True)

    def between_episodes(self) -> int:
        """Nothing to do: the thread goes on training while the vehicle is repositioned."""
        return 0

    @property
    def state(self) -> LearnerState:
        return self._state

    @property
    def error(self) -> BaseException | None:
        """The exception that ended the thread, if it failed."""
        return self._error

    @property
    def latest_snapshot(self) -> PolicySnapshot:
        return self.learner.latest_snapshot

    def on_control_step(self, tick_start_s: float | None = None) -> PolicySnapshot:
        """Report a control tick and get the snapshot to fly now; never waits for training.

        Call it once per tick; when that is late in the tick, pass ``tick_start_s``
        (``time.perf_counter()`` at the tick's start) so the guard protects the tick's start.
        """
        self.guard.tick(tick_start_s)
        return self.learner.latest_snapshot

    def start(self) -> None:
        if self._state is not LearnerState.NEW:
            raise RuntimeError(f"learner thread already {self._state.value}; make a new one")
        self._state = LearnerState.IDLE
        self._saved_switch_interval_s = sys.getswitchinterval()
        sys.setswitchinterval(min(self._saved_switch_interval_s,
                                  self.learner.config.gil_switch_interval_s))
        self._thread.start()

    def stop(self, timeout_s: float = 5.0) -> LearnerState:
        """Ask the thread to end after its current update; returns the final state."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout_s)
            if self._thread.is_alive():
                log.warning("learner thread did not stop within %.1f s; it is a daemon and "
                            "will end with the process", timeout_s)
        if self._saved_switch_interval_s is not None:
            sys.setswitchinterval(self._saved_switch_interval_s)
            self._saved_switch_interval_s = None
        return self._state

    def __enter__(self) -> LearnerThread:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _run(self) -> None:
        limit_torch_threads(self.learner.config.torch_threads)
        _lower_this_threads_priority(self.learner.config.thread_nice)
        try:
            while not self._stop.is_set():
                if self.learner.has_work:
                    self._state = LearnerState.TRAINING
                    self.guard.pause()
                    self.learner.train_until_converged(budget=1, publish_at_end=False)
                else:
                    self._state = LearnerState.IDLE
                    self.learner.dataset.wait_for_growth(self.learner.round_size, self.idle_wait_s)
        except Exception as exc:  # forwarded: state, error property and the log
            self._error = exc
            self._state = LearnerState.FAILED
            log.exception("learner thread failed; control keeps flying snapshot v%d",
                          self.learner.latest_snapshot.version)
            return
        self._state = LearnerState.STOPPED


def _lower_this_threads_priority(nice: int) -> None:
    """Raise the calling thread's niceness (Linux: per thread); elsewhere do nothing."""
    if nice <= 0 or not hasattr(os, "setpriority"):
        return
    try:
        tid = threading.get_native_id()
        os.setpriority(os.PRIO_PROCESS, tid, max(os.getpriority(os.PRIO_PROCESS, tid), nice))
    except OSError as exc:
        log.info("could not lower the learner thread's priority (%s); continuing", exc)


def make_runner(learner: Learner) -> BudgetedLearner | LearnerThread | LearnerProcess:
    """The runner the config asks for (``mode``): all offer start/on_control_step/stop/error.

    ``process`` needs a dataset recorded to a file (the child reads it) and raises ConfigError
    otherwise.
    """
    if learner.config.mode == "budgeted":
        return BudgetedLearner(learner)
    if learner.config.holdout_stop:
        log.warning("holdout_stop trains to its stopping rule between episodes in budgeted mode only; "
                    "the %s runner trains with the paper's loop (the held-out samples are still never "
                    "trained on)", learner.config.mode)
    if learner.config.mode == "process":
        return LearnerProcess(learner)
    return LearnerThread(learner)
