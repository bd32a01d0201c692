"""The NumPy trainer against the plain torch path (PolicyNet + F.mse_loss + autograd + RMSprop).

Two correct float32 implementations do not stay equal forever: when a ReLU pre-activation lands
within round-off of 0 the two sides may switch that unit for one sample differently, and
RMSprop's normalised step turns that into a weight difference of about lr/3. Over 300 updates
most seeds agree to 1e-7, the worst of 40 seeds drifted by 5e-3 (loss, relative) and 1.4e-3
(weights, relative L2), and torch in float64 drifts from torch in float32 just the same. So:

* every single update, started from the torch side's exact state, must agree to round-off
  (a 1 % change of lr is far above the bound), and
* whole loss curves of a few hundred updates must track each other (bounds well above the
  worst drift seen, far below any real change of semantics).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from companion.config import LearnerConfig
from companion.learning.dataset import DatasetView
from companion.learning.learner import Learner
from companion.learning.policy import Normalisation, PolicyNet, PolicySnapshot
from companion.learning.trainer import MlpTrainer, one_blas_thread

N_UPDATES = 300
STEP_LOSS_RTOL = 1e-5
STEP_W_MEDIAN_ATOL = 5e-7  # median over updates of max |w_numpy - w_torch|; lr +1 %: about 6e-6
STEP_W_MAX_ATOL = 1e-4  # any update (one ReLU flip moves a few weights by about 3e-5)
TRAJ_LOSS_MEDIAN_RTOL = 1e-4
TRAJ_LOSS_MAX_RTOL = 3e-2
TRAJ_W_REL_L2 = 1e-2


@pytest.fixture(scope="module", autouse=True)
def _one_thread() -> None:
    torch.set_num_threads(1)
    one_blas_thread()


def _data(seed: int = 0, n: int = 2000) -> tuple[np.ndarray, np.ndarray, Normalisation]:
    """A learnable, non-trivially scaled dataset (so the normalisation matters)."""
    rng = np.random.default_rng(seed)
    obs = rng.normal(size=(n, 15)) * rng.uniform(0.5, 3, 15) + rng.normal(0, 2, 15)
    gain = rng.normal(0, 0.4, size=(4, 15))
    act = np.clip(np.tanh(((obs - obs.mean(0)) / obs.std(0)) @ gain.T) + rng.normal(0, 0.1, (n, 4)), -1, 1)
    obs, act = obs.astype(np.float32), act.astype(np.float32)
    return obs, act, Normalisation(obs.mean(0), obs.std(0))


def _net(norm: Normalisation, seed: int = 0) -> PolicyNet:
    return PolicyNet(15, (130, 72, 40), init_std=0.1, generator=torch.Generator().manual_seed(seed),
                     normalisation=norm)


def _torch_run(net: PolicyNet, opt: torch.optim.Optimizer, obs: np.ndarray, act: np.ndarray,
               batches: list[np.ndarray]) -> np.ndarray:
    losses = []
    for idx in batches:
        loss = F.mse_loss(net(torch.from_numpy(obs[idx])), torch.from_numpy(act[idx]))
        losses.append(loss.item())
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
    return np.array(losses)


def _numpy_run(tr: MlpTrainer, obs: np.ndarray, act: np.ndarray, batches: list[np.ndarray]) -> np.ndarray:
    return np.array([tr.step(obs[idx], act[idx]) for idx in batches])


def _batches(n: int, count: int, size: int = 64, seed: int = 1) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [rng.integers(0, n, size=size) for _ in range(count)]


def _params(tr: MlpTrainer) -> np.ndarray:
    ws, bs = tr.weights()
    return np.concatenate([x.ravel() for pair in zip(ws, bs) for x in pair])


def _weight_diff(tr: MlpTrainer, net: PolicyNet) -> tuple[float, float]:
    """(max abs, relative L2) difference between the trainer's and the net's parameters."""
    mine, ref = _params(tr), np.concatenate([p.detach().numpy().ravel() for p in net.parameters()])
    return float(np.abs(mine - ref).max()), float(np.linalg.norm(mine - ref) / np.linalg.norm(ref))


def _assert_tracks(mine: np.ndarray, ref: np.ndarray, tr: MlpTrainer, net: PolicyNet) -> None:
    rel = np.abs(mine - ref) / ref
    assert np.median(rel) < TRAJ_LOSS_MEDIAN_RTOL and rel.max() < TRAJ_LOSS_MAX_RTOL, rel.max()
    assert _weight_diff(tr, net)[1] < TRAJ_W_REL_L2, _weight_diff(tr, net)


def _at_torch_state(net: PolicyNet, opt: torch.optim.Optimizer, **hyper: float) -> MlpTrainer:
    """A trainer holding the net's weights and the optimiser's RMSprop state."""
    snap = net.snapshot()
    tr = MlpTrainer(snap.weights, snap.biases, snap.normalisation.mean, snap.normalisation.std,
                    **({"lr": 1e-4} | hyper))
    params = list(net.parameters())
    if all(p in opt.state for p in params):
        tr.load_square_avgs([opt.state[p]["square_avg"].numpy() for p in params], int(opt.state[params[0]]["step"]))
    return tr


def _one_step_diffs(seed: int, **hyper: float) -> tuple[float, float, float, float]:
    """Along a torch trajectory, one NumPy update from each of its states; the differences:
    (worst loss rel, median and worst weights max-abs, worst square_avg relative L2)."""
    obs, act, norm = _data()
    net = _net(norm, seed)
    opt = torch.optim.RMSprop(net.parameters(), lr=1e-4, foreach=True)
    loss_rel, w_diff, sq_rel = [], [], []
    for idx in _batches(len(obs), N_UPDATES, seed=seed):
        tr = _at_torch_state(net, opt, **hyper)
        mine = tr.step(obs[idx], act[idx])
        ref = _torch_run(net, opt, obs, act, [idx])[0]
        loss_rel.append(abs(mine - ref) / ref)
        w_diff.append(_weight_diff(tr, net)[0])
        sq_ref = [opt.state[p]["square_avg"].numpy() for p in net.parameters()]
        sq_rel.append(max(float(np.linalg.norm(a - b) / np.linalg.norm(b))
                          for a, b in zip(tr.square_avgs(), sq_ref, strict=True)))
    return max(loss_rel), float(np.median(w_diff)), max(w_diff), max(sq_rel)


@pytest.mark.parametrize("seed", [0, 2])
def test_every_update_matches_torch_from_the_same_state(seed: int) -> None:
    loss_rel, w_median, w_max, sq_rel = _one_step_diffs(seed)
    assert loss_rel < STEP_LOSS_RTOL
    assert w_median < STEP_W_MEDIAN_ATOL and w_max < STEP_W_MAX_ATOL, (w_median, w_max)
    assert sq_rel < 1e-3


@pytest.mark.parametrize("change", [{"lr": 1.01e-4}, {"alpha": 0.991}, {"eps": 1e-6}])
def test_a_slightly_different_optimiser_is_caught(change: dict[str, float]) -> None:
    """The one-update bounds see a 1 % change of lr, 0.1 % of alpha, a wrong eps."""
    _, w_median, _, _ = _one_step_diffs(0, **change)
    assert w_median > 5 * STEP_W_MEDIAN_ATOL


@pytest.mark.parametrize(("seed", "batch_size"), [(0, 64), (1, 64), (2, 64), (0, 17)])
def test_loss_curve_and_weights_track_torch(seed: int, batch_size: int) -> None:
    obs, act, norm = _data()
    net = _net(norm, seed)
    tr = MlpTrainer.from_snapshot(net.snapshot(), batch_size=batch_size)
    opt = torch.optim.RMSprop(net.parameters(), lr=1e-4, foreach=True)
    batches = _batches(len(obs), N_UPDATES, batch_size, seed=seed)
    ref, mine = _torch_run(net, opt, obs, act, batches), _numpy_run(tr, obs, act, batches)
    assert ref[-1] < 0.5 * ref[0]  # it learns, so the comparison means something
    _assert_tracks(mine, ref, tr, net)


def test_the_learners_loss_curve_tracks_plain_torch() -> None:
    """The project's Learner (same seed, same minibatch draws) against autograd + RMSprop 1e-4,
    MSE, minibatch 64 over 300 updates."""
    obs, act, norm = _data()

    class Source:
        def __len__(self) -> int:
            return len(obs)

        def view(self) -> DatasetView:
            return DatasetView(obs, act)

        def wait_for_growth(self, known: int, timeout_s: float) -> int:
            return len(obs)

    learner = Learner(LearnerConfig(seed=3), Source(), normalisation=norm)
    net = PolicyNet.from_snapshot(learner.latest_snapshot)
    opt = torch.optim.RMSprop(net.parameters(), lr=1e-4)
    rng = np.random.default_rng(3)  # the Learner's own rng: default_rng(config.seed)
    batches = [rng.integers(0, len(obs), size=64) for _ in range(N_UPDATES)]
    mine = np.array([learner.step() for _ in range(N_UPDATES)])
    _assert_tracks(mine, _torch_run(net, opt, obs, act, batches), learner.trainer, net)


def test_the_optimiser_state_hands_over_between_trainers() -> None:
    """What the learner process gets: 100 updates, state() -> load_state() into a fresh trainer,
    100 more, equals 200 updates in one trainer; without the state it does not."""
    obs, act, norm = _data(seed=5)
    batches = _batches(len(obs), 200, seed=7)
    snap = _net(norm, 5).snapshot()
    whole = _numpy_run(MlpTrainer.from_snapshot(snap), obs, act, batches)
    first = MlpTrainer.from_snapshot(snap)
    part1 = _numpy_run(first, obs, act, batches[:100])
    second, stateless = MlpTrainer.from_snapshot(first.snapshot()), MlpTrainer.from_snapshot(first.snapshot())
    second.load_state(first.state())
    assert second.updates == 100
    np.testing.assert_array_equal(np.concatenate([part1, _numpy_run(second, obs, act, batches[100:])]), whole)
    lost = _numpy_run(stateless, obs, act, batches[100:])
    assert np.max(np.abs(lost - whole[100:]) / whole[100:]) > 3 * TRAJ_LOSS_MAX_RTOL
    with pytest.raises(ValueError):
        second.load_state({"square_avg": np.zeros(3), "updates": 1})


def test_snapshot_flies_like_the_net() -> None:
    obs, act, norm = _data()
    net = _net(norm)
    tr = MlpTrainer.from_snapshot(net.snapshot())
    _numpy_run(tr, obs, act, _batches(len(obs), 20))
    snap = tr.snapshot(version=20, dataset_size_trained=len(obs))
    assert isinstance(snap, PolicySnapshot) and snap.version == 20
    with torch.no_grad():
        expected = PolicyNet.from_snapshot(snap)(torch.from_numpy(obs[:50])).numpy()
    np.testing.assert_allclose(snap.act(obs[:50]), expected, atol=1e-6)
    assert not np.allclose(snap.act(obs[:50]), net.snapshot().act(obs[:50]), atol=1e-4)  # it trained


def test_non_finite_loss_raises_and_keeps_the_weights() -> None:
    obs, act, norm = _data()
    tr = MlpTrainer.from_snapshot(_net(norm).snapshot())
    before = _params(tr)
    bad = obs[:64].copy()
    bad[3, 2] = np.inf
    with pytest.raises(FloatingPointError), np.errstate(invalid="ignore"):
        tr.step(bad, act[:64])
    assert tr.updates == 0
    np.testing.assert_array_equal(before, _params(tr))
    with pytest.raises(ValueError):
        tr.step(obs[:64], act[:64, :3])
