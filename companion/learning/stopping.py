"""Training between episodes to a stopping rule, and publishing averaged weights.

The diagnosis (docs/learner.md, endpoint 4) found the final policies depend on the last
episode's few updates (redone with other minibatch seeds they land 7-33 times in 100
differently) and some are under-trained (trained to convergence, two Demo policies land 17 and
28 times more). The paper's round ends at the first minibatch loss below a threshold, which
says little about either. With ``holdout_stop``:

- a fixed share of the person's samples is held out (:class:`HoldoutSplit`: blocks of
  consecutive samples, chosen by the learner's seed, the same ones however the dataset grows)
  and never trained on, during episodes as between them;
- between episodes the learner trains in checks of ``holdout_check_every_updates`` updates until
  the loss on the held-out samples has not improved for ``holdout_patience_checks`` checks, or
  ``between_episode_updates`` have run (:class:`PatienceRule`);
- what it measures and publishes is an exponential moving average of the weights over the
  session's updates (:class:`WeightAverage`, ``weight_average_decay``; 0: the last weights),
  the average at the best check: a policy that is many minibatches' mean rather than one
  draw's last step, and never one the held-out samples judge worse than where the session
  began.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from companion.config import LearnerConfig
from companion.learning.dataset import DatasetView
from companion.learning.ensemble import EnsembleTrainer
from companion.learning.snapshot import PolicySnapshot
from companion.learning.trainer import MlpTrainer

HOLDOUT_STREAM = 0x401D
"""Mixed into the seed, so the held-out draw is a stream of its own (not the minibatches')."""


class HoldoutSplit:
    """Which rows are held out: row ``i`` is in block ``i // block_samples``, and each block is
    held out with probability ``share``, by a generator seeded from ``seed`` alone.

    A whole block goes, not single rows: consecutive samples are near-copies of each other, and
    a held-out row beside a trained one would say little. Row ``i``'s fate never changes as the
    dataset grows."""

    def __init__(self, share: float, block_samples: int, seed: int) -> None:
        if not 0.0 < share < 1.0 or block_samples < 1:
            raise ValueError(f"need 0 < share < 1 and block_samples >= 1, got {share} and {block_samples}")
        self.share, self.block_samples, self.seed = share, block_samples, seed
        self._held_blocks = np.zeros(0, bool)
        self._rows_for = -1
        self._training = self._held = np.zeros(0, np.int64)

    def held_out(self, n: int) -> np.ndarray:
        """The mask of held-out rows among the first ``n``."""
        blocks = -(-n // self.block_samples)
        if blocks > len(self._held_blocks):  # a fresh generator's first draws are the same draws
            draws = np.random.default_rng([self.seed, HOLDOUT_STREAM]).random(max(blocks, 2 * len(self._held_blocks)))
            self._held_blocks = draws < self.share
        return np.repeat(self._held_blocks[:blocks], self.block_samples)[:n]

    def _split(self, n: int) -> None:
        if n != self._rows_for:
            mask = self.held_out(n)
            self._training, self._held, self._rows_for = np.flatnonzero(~mask), np.flatnonzero(mask), n

    def training_rows(self, n: int) -> np.ndarray:
        """Indices of the rows among the first ``n`` that may be trained on."""
        self._split(n)
        return self._training

    def held_rows(self, n: int) -> np.ndarray:
        """Indices of the held-out rows among the first ``n``."""
        self._split(n)
        return self._held


class WeightAverage:
    """Exponential moving average of a trainer's flat parameters, updated after each update:
    ``avg += (1 - decay) * (params - avg)``, starting from the weights the session began with."""

    def __init__(self, start: np.ndarray, decay: float) -> None:
        self.values = np.array(start, np.float32, copy=True)
        self._rate = np.float32(1.0 - decay)
        self._scratch = np.empty_like(self.values)

    def update(self, params: np.ndarray) -> None:
        np.subtract(params, self.values, out=self._scratch)
        np.multiply(self._scratch, self._rate, out=self._scratch)
        np.add(self.values, self._scratch, out=self.values)


@dataclass
class PatienceRule:
    """Stop when the loss has not improved on its best for ``patience_checks`` checks."""

    patience_checks: int
    best_loss: float = math.inf
    best_check: int = -1
    checks: int = 0

    def check(self, loss: float) -> bool:
        """Record one check's loss; whether it is the best so far."""
        self.checks += 1
        if loss < self.best_loss:
            self.best_loss, self.best_check = loss, self.checks - 1
            return True
        return False

    @property
    def exhausted(self) -> bool:
        return self.checks - 1 - self.best_check >= self.patience_checks


@dataclass(frozen=True)
class StopResult:
    """What one session between episodes did."""

    updates: int
    checks: int
    best_check: int
    """0: the weights the session began with were never beaten on the held-out samples."""
    holdout_loss: float
    stopped_by: str
    """``patience``, ``cap`` (between_episode_updates) or ``no held-out samples`` (the paper's
    loop ran instead)."""


def snapshot_with(trainer: MlpTrainer | EnsembleTrainer, params: np.ndarray) -> PolicySnapshot:
    """The trainer's snapshot had it ``params`` (the trainer is left as it was)."""
    kept = np.array(trainer.flat_parameters(), copy=True)
    trainer.load_flat_parameters(params)
    try:
        return trainer.snapshot()
    finally:
        trainer.load_flat_parameters(kept)


def holdout_loss(snapshot: PolicySnapshot, view: DatasetView, rows: np.ndarray,
                 weights: np.ndarray | None) -> float:
    """The policy's mean squared error on ``rows`` of ``view`` (weighted as training is)."""
    err = np.mean((snapshot.act(view.obs[rows]) - view.actions[rows]) ** 2, axis=-1)
    return float(np.average(err, weights=None if weights is None else weights[rows]))


class HoldoutSession:
    """One session between episodes: the moving average of the weights, checked on the held-out
    rows; ``best`` is the average at the best check so far (check 0: where it began)."""

    def __init__(self, trainer: MlpTrainer | EnsembleTrainer, view: DatasetView, held_rows: np.ndarray,
                 weights: np.ndarray | None, config: LearnerConfig) -> None:
        self.trainer, self.view, self.held_rows, self.weights = trainer, view, held_rows, weights
        self.average = WeightAverage(trainer.flat_parameters(), config.weight_average_decay)
        self.rule = PatienceRule(config.holdout_patience_checks)
        self.best = self.average.values.copy()
        self.check()

    def after_update(self) -> None:
        self.average.update(self.trainer.flat_parameters())

    def check(self) -> None:
        """Score the average on the held-out rows; keep it if it is the best so far."""
        loss = holdout_loss(snapshot_with(self.trainer, self.average.values), self.view, self.held_rows, self.weights)
        if self.rule.check(loss):
            self.best = self.average.values.copy()

    @property
    def done(self) -> bool:
        return self.rule.exhausted

    def result(self, updates: int) -> StopResult:
        return StopResult(updates, self.rule.checks, self.rule.best_check, self.rule.best_loss,
                          "patience" if self.done else "cap")
