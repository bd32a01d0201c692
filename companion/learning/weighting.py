"""Intervention weighting: the person's corrections count more in the loss than their
demonstrations.

Interventions are a few percent of a CoL dataset and are fitted less well than the
demonstrations (docs/learner.md, "What the diagnosis found", endpoint 4); they are also
exactly the states where the policy went wrong. Intervention Weighted Regression (Mandlekar et
al. 2020) and Sirius (Liu et al. 2022) weight them above the rest; Sirius also singles out
the moments around a take-over. Here every sample has a weight:

- a demonstration sample: 1;
- an intervention sample: ``intervention_weight``;
- the first ``takeover_steps`` samples of each take-over: ``takeover_weight`` (instead).

The steps *before* a take-over, which Sirius weights too, are flown by the policy and never
recorded (only the person's samples are, DESIGN.md): the dataset has no such rows. The first
steps of a take-over are the person's answer to the state that made them take over.

A take-over is a run of intervention samples of one episode at consecutive control steps; a
step not recorded (a stale frame, the person letting go) ends it. In a minibatch the loss is
the weighted mean, ``sum_i w_i |y_i - t_i|^2 / (4 sum_i w_i)``: with all weights 1 it is the
paper's MSE, and the loss threshold keeps its meaning. Only training is weighted: nothing
travels with a checkpoint.
"""

from __future__ import annotations

import numpy as np

from companion.config import LearnerConfig
from companion.learning.dataset import DatasetView


def weighting_on(config: LearnerConfig) -> bool:
    """Whether any sample weighs other than 1 (off: the paper's unweighted MSE, bit for bit)."""
    return config.intervention_weight != 1.0 or (config.takeover_steps > 0 and config.takeover_weight != 1.0)


def takeover_positions(intervention: np.ndarray, episode: np.ndarray, step: np.ndarray) -> np.ndarray:
    """Per row: 0 for a take-over's first sample, 1 for its second, ...; -1 for a demonstration."""
    rows = np.arange(len(intervention))
    continues = np.zeros(len(intervention), bool)  # the row before is the same take-over's
    continues[1:] = intervention[:-1] & (episode[1:] == episode[:-1]) & (step[1:] - step[:-1] == 1)
    starts = intervention & ~continues
    last_start = np.maximum.accumulate(np.where(starts, rows, -1)) if len(rows) else rows
    return np.where(intervention, rows - last_start, -1)


def sample_weights(config: LearnerConfig, view: DatasetView) -> np.ndarray:
    """Every row's weight in the loss (float32), as the module docstring says."""
    if view.intervention is None or view.episode is None or view.step is None:
        raise ValueError("intervention weighting needs each sample's source, episode and step; "
                         "this dataset view does not keep them")
    weights = np.where(view.intervention, np.float32(config.intervention_weight), np.float32(1.0))
    if config.takeover_steps > 0:
        position = takeover_positions(view.intervention, view.episode, view.step)
        first_steps = (position >= 0) & (position < config.takeover_steps)
        weights[first_steps] = np.float32(config.takeover_weight)
    return weights.astype(np.float32)


class WeightCache:
    """The weights of the newest view, recomputed only when the dataset changed."""

    def __init__(self, config: LearnerConfig) -> None:
        self.config = config
        self._view: DatasetView | None = None  # held, so its rows (never rewritten) stay the key
        self._weights = np.ones(0, np.float32)

    def of(self, view: DatasetView) -> np.ndarray:
        """``sample_weights`` of ``view``; the same view again reuses them."""
        if view is not self._view:
            self._weights, self._view = sample_weights(self.config, view), view
        return self._weights
