"""How well a policy fits the person's samples: the MSE on all of them and on the
interventions alone.

Interventions are a few percent of a CoL dataset, so the learner's minibatch loss says little
about them; this is logged per episode to show whether the corrections are learned.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from companion.learning.dataset import DatasetView
from companion.learning.snapshot import PolicySnapshot


@dataclass(frozen=True)
class Fit:
    """Mean squared error of the policy's actions against the recorded ones (NaN: no samples)."""

    loss_all: float
    loss_intervention: float


def _mse(snapshot: PolicySnapshot, obs: np.ndarray, actions: np.ndarray) -> float:
    if len(obs) == 0:
        return math.nan
    return float(np.mean((snapshot.act(obs) - actions) ** 2))


def fit_of(snapshot: PolicySnapshot, view: DatasetView) -> Fit:
    """The snapshot's fit to every sample of ``view``, and to its intervention samples."""
    mask = view.intervention if view.intervention is not None else np.zeros(len(view), bool)
    return Fit(_mse(snapshot, view.obs, view.actions), _mse(snapshot, view.obs[mask], view.actions[mask]))
