"""The paper's Update-Policy procedure (Algorithm 1): supervised updates on the human dataset.

``Learner`` owns the model's trainer (:class:`~companion.learning.trainer.MlpTrainer`: MSE,
RMSProp; or, with ``ensemble_members`` > 1, :class:`~companion.learning.ensemble.EnsembleTrainer`:
K networks, each on its own minibatches) and the paper's loop. ``step()`` is one plain, deterministic
update (seeded minibatch); ``train_until_converged()`` is the paper's loop - whenever the dataset
holds new samples, update until the minibatch loss is below the threshold or the round reaches
``max_updates`` - and can stop after a budget of updates and resume where it was.

After updates the learner publishes an immutable :class:`PolicySnapshot` with one assignment;
``latest_snapshot`` is read by the control loop without any lock. How the loop is *run* lives
apart, in :mod:`companion.learning.runners` (budgeted, thread) and
:mod:`companion.learning.learner_process` (a child process).
"""

from __future__ import annotations

import logging
import math
import threading
from dataclasses import dataclass
from enum import Enum
from typing import Protocol

import numpy as np

from companion.config import LearnerConfig
from companion.errors import ConfigError
from companion.learning.augment import Mirror
from companion.learning.dataset import DatasetView
from companion.learning.ensemble import EnsembleSnapshot, EnsembleTrainer
from companion.learning.snapshot import Normalisation, PolicySnapshot, random_snapshot
from companion.learning.stopping import HoldoutSession, HoldoutSplit, StopResult
from companion.learning.trainer import MlpTrainer, one_blas_thread
from companion.learning.weighting import WeightCache, weighting_on
from companion.msg.observation import OBS_DIM, OBS_NAMES

log = logging.getLogger(__name__)


class SampleSource(Protocol):
    """What the learner needs from a dataset (HumanDataset provides it)."""

    def __len__(self) -> int: ...

    def view(self) -> DatasetView: ...

    def wait_for_growth(self, known: int, timeout_s: float) -> int: ...


@dataclass(frozen=True)
class TrainResult:
    """What one call of ``train_until_converged`` did."""

    updates: int
    loss: float
    converged: bool
    round_updates: int
    capped: bool
    dataset_size: int


class Learner:
    """Model + RMSProp + MSE on the human dataset; publishes snapshots.

    Not meant to be stepped from two threads at once (a lock serialises it anyway); the
    snapshot it publishes may be read from any thread at any time.
    """

    def __init__(
        self,
        config: LearnerConfig,
        dataset: SampleSource,
        *,
        obs_dim: int = OBS_DIM,
        normalisation: Normalisation | None = None,
        initial: PolicySnapshot | None = None,
        rng: np.random.Generator | None = None,
    ) -> None:
        self.config = config
        self.dataset = dataset
        self.rng = rng if rng is not None else np.random.default_rng(config.seed)
        one_blas_thread()  # process-wide: threaded BLAS is ~10x slower on these small products
        self.trainer = self._make_trainer(config, obs_dim, normalisation, initial)
        self.updates = initial.version if initial else 0
        self.last_loss = math.nan
        self._lock = threading.RLock()
        self._trained_size = initial.dataset_size_trained if initial else 0
        self._round_size = 0
        self._round_updates = 0
        self._converged = False
        self._since_publish = 0
        self._latest = self.trainer.snapshot(self.updates, self._trained_size)
        self._mirror = self._mirror_for(config, obs_dim)
        self._weights = WeightCache(config) if weighting_on(config) else None
        self._split = (HoldoutSplit(config.holdout_share, config.holdout_block_samples, config.seed)
                       if config.holdout_stop else None)
        self._settled_size = -1  # dataset size of the last holdout_stop session

    @classmethod
    def _make_trainer(cls, config: LearnerConfig, obs_dim: int, normalisation: Normalisation | None,
                      initial: PolicySnapshot | None) -> MlpTrainer | EnsembleTrainer:
        """One network (the paper's), or ``ensemble_members`` of them trained side by side; the
        loss's gradient is Huber's where ``huber_delta`` is set."""
        trainer = cls._make_network_trainer(config, obs_dim, normalisation, initial)
        trainer.huber_delta = config.huber_delta
        return trainer

    @classmethod
    def _make_network_trainer(cls, config: LearnerConfig, obs_dim: int, normalisation: Normalisation | None,
                              initial: PolicySnapshot | None) -> MlpTrainer | EnsembleTrainer:
        lr, batch = config.learning_rate, config.batch_size
        k = config.ensemble_members
        if k == 1:
            return MlpTrainer.from_snapshot(cls._initial_weights(config, obs_dim, normalisation, initial),
                                           lr=lr, batch_size=batch)
        if initial is not None:
            if not isinstance(initial, EnsembleSnapshot) or initial.members != k:
                have = initial.members if isinstance(initial, EnsembleSnapshot) else 1
                raise ConfigError(f"initial policy has {have} member(s), the config asks for an ensemble of {k}; "
                                  "start fresh or set learner.ensemble_members to match")
            cls._initial_weights(config, obs_dim, normalisation, initial.member(0))  # checks the shape
            return EnsembleTrainer.from_snapshot(initial, lr=lr, batch_size=batch)
        members = [cls._initial_weights(config.model_copy(update={"seed": config.seed + m}), obs_dim,
                                         normalisation, None) for m in range(k)]
        return EnsembleTrainer.from_snapshot(EnsembleSnapshot.of_members(members), lr=lr, batch_size=batch)

    @staticmethod
    def _mirror_for(config: LearnerConfig, obs_dim: int) -> Mirror | None:
        """The left/right mirror of the observation the dataset records (``mirror_augment``)."""
        if not config.mirror_augment:
            return None
        if obs_dim != OBS_DIM:
            raise ConfigError(f"mirror_augment knows the {OBS_DIM}-value observation {OBS_NAMES}, the learner's "
                              f"has {obs_dim} values; set mirror_augment = false")
        return Mirror(OBS_NAMES)

    @staticmethod
    def _initial_weights(config: LearnerConfig, obs_dim: int, normalisation: Normalisation | None,
                         initial: PolicySnapshot | None) -> PolicySnapshot:
        """The weights to start from: ``initial`` as it is, or a fresh seeded network drawn by
        torch (by NumPy where torch is not installed: the lean runtime flies and learns too)."""
        if initial is not None:
            if initial.obs_dim != obs_dim or initial.hidden != tuple(config.hidden):
                raise ConfigError(
                    f"initial policy is {initial.obs_dim}->{initial.hidden}, the config asks for "
                    f"{obs_dim}->{tuple(config.hidden)}; start fresh or use a matching config"
                )
            return initial
        try:
            import torch

            from companion.learning.policy import PolicyNet
        except ImportError:
            log.warning("torch is not installed: the fresh policy's weights are drawn by NumPy (the "
                        "same distribution, another draw than an install with torch makes)")
            return random_snapshot(obs_dim, config.hidden, init_std=config.init_std, seed=config.seed,
                                   normalisation=normalisation)
        generator = torch.Generator().manual_seed(config.seed)
        return PolicyNet(obs_dim, config.hidden, init_std=config.init_std, generator=generator,
                         normalisation=normalisation).snapshot()

    # -- the update ---------------------------------------------------------------------
    def step(self) -> float:
        """One update on a minibatch drawn with replacement; returns its MSE before the update.

        Raises ValueError on an empty dataset and FloatingPointError on a non-finite loss
        (the weights are left untouched, so the last snapshot stays good).
        """
        with self._lock:
            view = self.dataset.view()
            if self._trainable_size(len(view)) == 0:
                raise ValueError("the dataset holds no samples to train on (empty, or all held out); "
                                 "record samples before training")
            obs, actions, weights = self._minibatch(view)
            try:
                value = self.trainer.step(obs, actions, weights)
            except FloatingPointError as exc:
                raise FloatingPointError(
                    f"{exc}; check the dataset for extreme observations or lower learning_rate"
                ) from None
            self.updates += 1
            self._trained_size = len(view)
            self._since_publish += 1
            self.last_loss = value
            return value

    def _minibatch(self, view: DatasetView) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """``batch_size`` rows drawn with replacement (an ensemble: a draw for every member),
        followed by their mirror images with ``mirror_augment``; their weights in the loss
        (None: all equal, the paper's MSE). With ``holdout_stop`` only the training rows are
        drawn from."""
        k = self.config.ensemble_members
        rows = None if self._split is None else self._split.training_rows(len(view))
        idx = self.rng.integers(0, len(view) if rows is None else len(rows),
                                size=self.config.batch_size if k == 1 else (k, self.config.batch_size))
        if rows is not None:  # holdout_stop: the held-out rows are never drawn
            idx = rows[idx]
        obs, actions = view.obs[idx], view.actions[idx]
        weights = None if self._weights is None else self._weights.of(view)[idx]
        if self._mirror is not None:
            obs, actions = self._mirror.with_mirrored(obs, actions)
            weights = None if weights is None else np.concatenate([weights, weights], axis=-1)
        return obs, actions, weights

    def _trainable_size(self, n: int) -> int:
        """How many of the first ``n`` rows may be trained on (all but the held-out ones)."""
        return n if self._split is None else len(self._split.training_rows(n))

    # -- the paper's loop ---------------------------------------------------------------
    @property
    def has_work(self) -> bool:
        """New samples exist (or some were discarded), or the current round has neither
        converged nor hit the cap; never on a dataset with nothing to train on."""
        n = len(self.dataset)
        if self._trainable_size(n) == 0:
            return False
        if n != self._round_size:
            return True
        return self._round_size > 0 and not self._converged and not self._capped

    @property
    def _capped(self) -> bool:
        return self._round_updates >= self.config.max_updates

    @property
    def round_size(self) -> int:
        """Dataset size at which the current round (re)started."""
        return self._round_size

    def _restart_round_if_new_samples(self) -> None:
        n = len(self.dataset)
        if n != self._round_size and n > 0:  # fewer: an episode was discarded, the round starts over
            self._round_size, self._round_updates, self._converged = n, 0, False

    def train_until_converged(self, budget: int | None = None, *,
                              publish_at_end: bool = True) -> TrainResult:
        """Run the paper's loop for at most ``budget`` updates (None: until the round ends).

        Publishes a snapshot every ``publish_every_updates`` updates, right after the first
        update that saw new samples, when the round ends, and (``publish_at_end``) at the end
        of the call if anything changed.
        """
        with self._lock:
            done = 0
            while budget is None or done < budget:
                self._restart_round_if_new_samples()
                if not self.has_work:
                    break
                loss = self.step()
                done += 1
                self._round_updates += 1
                self._converged = loss < self.config.loss_threshold
                if self._should_publish():
                    self.publish()
            if self._since_publish and (publish_at_end or not self.has_work):
                self.publish()
            return TrainResult(done, self.last_loss, self._converged, self._round_updates,
                               self._capped and not self._converged, len(self.dataset))

    # -- holdout_stop: between episodes ------------------------------------------------
    @property
    def has_unsettled_samples(self) -> bool:
        """The dataset changed since the last :meth:`train_to_holdout_stop` and has rows to
        train on (the paper's round may have converged meanwhile: that does not count)."""
        n = len(self.dataset)
        return n != self._settled_size and self._trainable_size(n) > 0

    def train_to_holdout_stop(self, cap: int) -> StopResult:
        """Train until the held-out loss of the weights' moving average has not improved for
        ``holdout_patience_checks`` checks, or for ``cap`` updates; then fly (and train on from)
        the average at its best check (:mod:`companion.learning.stopping`). Without held-out
        rows yet (the first samples), the paper's loop runs instead, for ``cap`` updates at most.
        """
        with self._lock:
            if self._split is None:
                raise ConfigError("train_to_holdout_stop needs learner.holdout_stop = true")
            view = self.dataset.view()
            held = self._split.held_rows(len(view))
            if len(held) == 0:
                ran = self.train_until_converged(budget=cap).updates
                return StopResult(ran, 0, 0, math.nan, "no held-out samples")
            session = HoldoutSession(self.trainer, view, held, None if self._weights is None else self._weights.of(view),
                                     self.config)
            done = 0
            while done < cap and not session.done:
                for _ in range(min(self.config.holdout_check_every_updates, cap - done)):
                    self.step()
                    session.after_update()
                    done += 1
                session.check()
            self.trainer.load_flat_parameters(session.best)
            self._settled_size = self._round_size = len(view)
            self._round_updates, self._converged = 0, True  # settled: the next samples start a round
            self.publish()
            return session.result(done)

    def _should_publish(self) -> bool:
        fresh_data = self._trained_size > self._latest.dataset_size_trained
        return fresh_data or self._since_publish >= self.config.publish_every_updates

    # -- snapshots ----------------------------------------------------------------------
    def publish(self) -> PolicySnapshot:
        """Copy the weights into a new snapshot and swap it in with one assignment."""
        with self._lock:
            snap = self.trainer.snapshot(self.updates, self._trained_size)
            self._latest = snap
            self._since_publish = 0
            return snap

    @property
    def latest_snapshot(self) -> PolicySnapshot:
        """The newest complete snapshot; never waits for training."""
        return self._latest

    def adopt(self, snapshot: PolicySnapshot) -> None:
        """Make a snapshot trained elsewhere (the learner process) this learner's latest.

        One assignment, cheap enough for the control tick, so checkpoints and ``latest_snapshot``
        see the process's training. The trainer here is not changed: to train in this process
        afterwards, build a new Learner with ``initial=snapshot``.
        """
        self._latest = snapshot


class LearnerState(Enum):
    """Life of the learner thread; FAILED and STOPPED are final."""

    NEW = "new"
    IDLE = "idle"
    TRAINING = "training"
    FAILED = "failed"
    STOPPED = "stopped"
