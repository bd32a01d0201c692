"""The policy's fit to all samples and to the interventions alone, and the mask behind it."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from companion.learning.dataset import HumanDataset
from companion.learning.fit import fit_of
from companion.learning.policy import Normalisation, PolicySnapshot
from companion.msg.sample import Sample, Source


def zero_policy() -> PolicySnapshot:
    """Acts 0 everywhere: the MSE is then the mean of the squared recorded actions."""
    weights = (np.zeros((4, 15), np.float32),)
    return PolicySnapshot(weights, (np.zeros(4, np.float32),), Normalisation.identity(), 0, 0)


def sample(step: int, source: Source, action: float) -> Sample:
    return Sample(0, step, 0.1 * step, source, np.zeros(15, np.float32), np.full(4, action, np.float32))


def test_fit_separates_intervention_samples_and_survives_a_reload(tmp_path: Path) -> None:
    path = tmp_path / "human.csv"
    with HumanDataset(path) as ds:
        ds.extend([sample(0, Source.DEMONSTRATION, 0.1), sample(1, Source.DEMONSTRATION, 0.1),
                   sample(2, Source.INTERVENTION, 0.5)])
        fit = fit_of(zero_policy(), ds.view())
        assert ds.view().intervention is not None
        assert ds.view().intervention.tolist() == [False, False, True]
    assert math.isclose(fit.loss_all, (0.01 + 0.01 + 0.25) / 3, rel_tol=1e-5)
    assert math.isclose(fit.loss_intervention, 0.25, rel_tol=1e-5)
    with HumanDataset(path) as again:  # the mask is rebuilt from the file's source column
        assert fit_of(zero_policy(), again.view()) == fit


def test_no_intervention_samples_is_nan_not_zero() -> None:
    ds = HumanDataset(None)
    ds.append(sample(0, Source.DEMONSTRATION, 0.2))
    fit = fit_of(zero_policy(), ds.view())
    assert math.isclose(fit.loss_all, 0.04, rel_tol=1e-5) and math.isnan(fit.loss_intervention)
