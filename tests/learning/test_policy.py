"""PolicyNet and PolicySnapshot: shapes, bounds, normalisation, NumPy == torch, immutability."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from companion.learning.policy import ACT_DIM, Normalisation, PolicyNet, PolicySnapshot
from companion.msg.observation import OBS_DIM


def _net(seed: int = 0, **kw) -> PolicyNet:
    return PolicyNet(generator=torch.Generator().manual_seed(seed), **kw)


def test_paper_shape_and_normal_init() -> None:
    net = _net(init_std=0.1)
    assert net.obs_dim == OBS_DIM == 15
    assert net.hidden == (130, 72, 40)
    assert net.linears[-1].out_features == ACT_DIM == 4
    w = net.linears[1].weight.detach().numpy()
    assert abs(float(w.std()) - 0.1) < 0.005 and abs(float(w.mean())) < 0.005
    assert all(float(layer.bias.detach().abs().sum()) == 0.0 for layer in net.linears)


def test_same_seed_same_weights_other_seed_differs() -> None:
    a, b, c = _net(1).snapshot(), _net(1).snapshot(), _net(2).snapshot()
    assert all(np.array_equal(x, y) for x, y in zip(a.weights, b.weights, strict=True))
    assert not np.array_equal(a.weights[0], c.weights[0])


def test_outputs_bounded_even_for_huge_inputs(rng: np.random.Generator) -> None:
    snap = _net(init_std=1.0).snapshot()
    out = snap.act(rng.normal(0, 1e4, size=(500, 15)))
    assert out.shape == (500, 4)
    assert np.all(np.abs(out) <= 1.0) and np.any(np.abs(out) > 0.99)


def test_numpy_act_matches_torch_forward(rng: np.random.Generator) -> None:
    norm = Normalisation(rng.normal(size=15), rng.uniform(0.5, 3.0, size=15))
    net = _net(3, normalisation=norm, init_std=0.3)
    x = rng.normal(0, 2, size=(64, 15)).astype(np.float32)
    with torch.no_grad():
        expected = net(torch.from_numpy(x)).numpy()
    snap = net.snapshot()
    np.testing.assert_allclose(snap.act(x), expected, atol=1e-5)
    np.testing.assert_allclose(snap.act(x[0]), expected[0], atol=1e-5)


def test_normalisation_is_applied() -> None:
    """Shifting the input and the mean together leaves the output unchanged."""
    base = _net(4)
    shifted = PolicyNet.from_snapshot(
        PolicySnapshot(base.snapshot().weights, base.snapshot().biases,
                       Normalisation(np.full(15, 10.0), np.full(15, 2.0)))
    )
    x = np.linspace(-1, 1, 15, dtype=np.float32)
    np.testing.assert_allclose(shifted.snapshot().act(10.0 + 2.0 * x), base.snapshot().act(x), atol=1e-6)


def test_snapshot_is_immutable_and_detached() -> None:
    net = _net(5)
    snap = net.snapshot(version=3, dataset_size_trained=7)
    with pytest.raises(ValueError):
        snap.weights[0][0, 0] = 1.0
    with pytest.raises(AttributeError):
        snap.version = 4  # type: ignore[misc]
    before = snap.act(np.ones(15, np.float32)).copy()
    with torch.no_grad():
        for p in net.parameters():
            p.add_(1.0)
    np.testing.assert_array_equal(snap.act(np.ones(15, np.float32)), before)


def test_from_snapshot_round_trip(rng: np.random.Generator) -> None:
    snap = _net(6).snapshot()
    again = PolicyNet.from_snapshot(snap).snapshot()
    x = rng.normal(size=(10, 15))
    np.testing.assert_array_equal(again.act(x), snap.act(x))


def test_invalid_snapshots_refused() -> None:
    snap = _net(7).snapshot()
    w = list(snap.weights)
    w[1] = np.zeros((72, 99), np.float32)
    with pytest.raises(ValueError, match="layer 1"):
        PolicySnapshot(tuple(w), snap.biases, snap.normalisation)
    w = [x.copy() for x in snap.weights]
    w[2][0, 0] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        PolicySnapshot(tuple(w), snap.biases, snap.normalisation)
    with pytest.raises(ValueError, match="std > 0"):
        Normalisation(np.zeros(15), np.zeros(15))
    with pytest.raises(ValueError, match="expects 15"):
        snap.act(np.zeros(14))


