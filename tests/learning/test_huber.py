"""The Huber switch (``huber_delta``): the update follows torch's Huber gradient, the loss it
reports stays the MSE, and it is off (the paper's MSE, bit for bit) unless set."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from companion.config import LearnerConfig
from companion.experiment.grid import ADDED_LATER
from companion.learning.dataset import DatasetView
from companion.learning.ensemble import EnsembleSnapshot, EnsembleTrainer
from companion.learning.learner import Learner
from companion.learning.policy import PolicyNet
from companion.learning.trainer import MlpTrainer

DELTA = 0.1


@pytest.fixture(autouse=True)
def _one_thread() -> None:
    torch.set_num_threads(1)


def _net(seed: int = 4) -> PolicyNet:
    return PolicyNet(15, (130, 72, 40), generator=torch.Generator().manual_seed(seed))


def _batch(n: int = 64, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Rows whose labels are far from a fresh net's outputs in places (a lapse's stale stick)."""
    rng = np.random.default_rng(seed)
    obs = rng.normal(size=(n, 15)).astype(np.float32)
    act = np.tanh(obs[:, :4] * 0.7)
    act[rng.random(n) < 0.2] *= -1  # a fifth of the rows say the opposite
    return obs, act.astype(np.float32)


def _torch_step(net: PolicyNet, obs: np.ndarray, act: np.ndarray, weights: np.ndarray | None) -> float:
    """One RMSprop step of torch on 2 x Huber (equal to the MSE below delta), weighted per row
    as the trainer weighs (weights scaled to a mean of 1); returns the MSE before the step."""
    opt = torch.optim.RMSprop(net.parameters(), lr=1e-4)
    y, t = net(torch.from_numpy(obs)), torch.from_numpy(act)
    per_element = 2 * F.huber_loss(y, t, reduction="none", delta=DELTA)
    w = torch.ones(len(obs), 1) if weights is None else torch.from_numpy(weights / weights.mean())[:, None]
    loss = (per_element * w).mean()
    opt.zero_grad()
    loss.backward()
    mse = float(((y - t) ** 2 * w).mean().detach())
    opt.step()
    return mse


def _flat(net: PolicyNet) -> np.ndarray:
    return np.concatenate([p.detach().numpy().ravel() for p in net.parameters()])


def _trainer_flat(tr: MlpTrainer) -> np.ndarray:
    ws, bs = tr.weights()
    return np.concatenate([x.ravel() for pair in zip(ws, bs) for x in pair])


@pytest.mark.parametrize("weighted", [False, True])
def test_one_update_is_torchs_huber_step_and_reports_the_mse(weighted: bool) -> None:
    obs, act = _batch()
    weights = np.random.default_rng(1).uniform(0.5, 3.0, len(obs)).astype(np.float32) if weighted else None
    net = _net()
    tr = MlpTrainer.from_snapshot(net.snapshot(), lr=1e-4)
    tr.huber_delta = DELTA
    loss = tr.step(obs, act, weights)
    mse = _torch_step(net, obs, act, weights)
    assert loss == pytest.approx(mse, rel=1e-5)
    np.testing.assert_allclose(_trainer_flat(tr), _flat(net), atol=2e-6)


def test_the_cap_changes_the_update() -> None:
    """Capped and plain updates differ on labels far off (else the test above proves nothing)."""
    obs, act = _batch()
    snap = _net().snapshot()
    plain, capped = MlpTrainer.from_snapshot(snap), MlpTrainer.from_snapshot(snap)
    capped.huber_delta = DELTA
    assert plain.step(obs, act) == capped.step(obs, act)  # the same MSE before the update
    assert np.abs(_trainer_flat(plain) - _trainer_flat(capped)).max() > 1e-6


def test_a_cap_above_every_error_is_the_mse_bit_for_bit() -> None:
    obs, act = _batch()
    snap = _net().snapshot()
    plain, capped = MlpTrainer.from_snapshot(snap), MlpTrainer.from_snapshot(snap)
    capped.huber_delta = 2.0  # errors of tanh outputs against labels in [-1, 1] are below 2
    for _ in range(3):
        plain.step(obs, act)
        capped.step(obs, act)
    np.testing.assert_array_equal(_trainer_flat(plain), _trainer_flat(capped))


def test_an_ensembles_members_cap_as_one_network_does() -> None:
    members = [_net(s).snapshot() for s in (1, 2)]
    obs, act = _batch(16)
    obs, act = obs.reshape(2, 8, 15), act.reshape(2, 8, 4)
    ens = EnsembleTrainer.from_snapshot(EnsembleSnapshot.of_members(members), batch_size=8)
    ens.huber_delta = DELTA
    ens.step(obs, act)
    for k, member in enumerate(members):
        alone = MlpTrainer.from_snapshot(member, batch_size=8)
        alone.huber_delta = DELTA
        alone.step(obs[k], act[k])
        np.testing.assert_allclose(ens.weights()[0][0][k], alone.weights()[0][0], atol=2e-6)


def test_the_learner_sets_the_cap_from_its_config_and_it_is_off_by_default() -> None:
    obs, act = _batch(200)
    view = DatasetView(obs, act)
    assert Learner(LearnerConfig(), view).trainer.huber_delta == 0.0
    assert Learner(LearnerConfig(huber_delta=DELTA), view).trainer.huber_delta == DELTA
    assert Learner(LearnerConfig(huber_delta=DELTA, ensemble_members=2), view).trainer.huber_delta == DELTA
    assert ADDED_LATER[("learner", "huber_delta")] == 0.0  # off: committed trials keep their fingerprint
    with pytest.raises(ValueError):
        LearnerConfig(huber_delta=-0.1)
