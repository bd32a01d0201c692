"""Intervention weighting: which samples weigh what, that the weights reach the loss and its
gradient, and that with every weight 1 the learner trains exactly as before."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from companion.config import LearnerConfig
from companion.learning.dataset import HumanDataset
from companion.learning.ensemble import EnsembleSnapshot, EnsembleTrainer
from companion.learning.learner import Learner
from companion.learning.learner_process import CsvTail
from companion.learning.policy import PolicyNet
from companion.learning.trainer import MlpTrainer
from companion.learning.weighting import sample_weights, takeover_positions, weighting_on
from companion.msg.sample import Sample, Source

DEM, INT = Source.DEMONSTRATION, Source.INTERVENTION
# (episode, step, source): a demonstration episode, then an episode with three take-overs (the
# second begins after a step not recorded), then a take-over that goes on into a new episode.
ROWS = [(0, 0, DEM), (0, 1, DEM), (0, 2, DEM),
        (1, 5, INT), (1, 6, INT), (1, 7, INT), (1, 9, INT), (1, 10, INT), (1, 20, INT),
        (2, 0, INT), (2, 1, INT)]
POSITIONS = [-1, -1, -1, 0, 1, 2, 0, 1, 0, 0, 1]


def _fill(ds: HumanDataset, rng: np.random.Generator, rows: list[tuple[int, int, Source]] = ROWS) -> None:
    ds.extend(Sample(e, s, 0.1 * s, src, rng.normal(size=15), rng.uniform(-1, 1, 4)) for e, s, src in rows)


def test_takeover_positions_count_from_each_takeovers_first_sample(rng: np.random.Generator) -> None:
    ds = HumanDataset(None)
    _fill(ds, rng)
    v = ds.view()
    assert v.intervention is not None and v.episode is not None and v.step is not None
    assert takeover_positions(v.intervention, v.episode, v.step).tolist() == POSITIONS
    assert takeover_positions(np.zeros(0, bool), np.zeros(0, int), np.zeros(0, int)).tolist() == []


def test_weights_by_source_and_takeover_step(rng: np.random.Generator) -> None:
    ds = HumanDataset(None)
    _fill(ds, rng)
    cfg = LearnerConfig(intervention_weight=3.0, takeover_steps=2, takeover_weight=5.0)
    assert sample_weights(cfg, ds.view()).tolist() == [1, 1, 1, 5, 5, 3, 5, 5, 5, 5, 5]
    cfg = LearnerConfig(intervention_weight=3.0)
    assert sample_weights(cfg, ds.view()).tolist() == [1, 1, 1] + [3] * 8


def test_off_means_every_weight_is_one() -> None:
    assert not weighting_on(LearnerConfig())
    assert not weighting_on(LearnerConfig(takeover_steps=4))  # takeover_weight still 1
    assert not weighting_on(LearnerConfig(takeover_weight=4.0))  # no take-over steps
    assert weighting_on(LearnerConfig(intervention_weight=2.0))
    assert weighting_on(LearnerConfig(takeover_steps=4, takeover_weight=2.0))


def test_the_file_and_its_tail_keep_source_episode_and_step(tmp_path: Path, rng: np.random.Generator) -> None:
    """What the learner process (CsvTail) and a resumed dataset see: the same columns."""
    with HumanDataset(tmp_path / "human.csv") as ds:
        _fill(ds, rng)
        live = ds.view()
    for view in (HumanDataset(tmp_path / "human.csv").view(), CsvTail(tmp_path / "human.csv").view()):
        for name in ("intervention", "episode", "step"):
            assert np.array_equal(getattr(view, name), getattr(live, name)), name


def _data(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    obs = rng.normal(size=(n, 15)).astype(np.float32)
    return obs, np.tanh(obs[:, :4] * 0.7).astype(np.float32)


def test_integer_weights_train_as_repeated_rows(rng: np.random.Generator) -> None:
    """The weighted loss and its update equal those of the plain MSE on a batch in which each
    row appears as often as its weight: the weights reach the loss and its gradient."""
    snap = PolicyNet(15, (130, 72, 40), generator=torch.Generator().manual_seed(4)).snapshot()
    obs, act = _data(rng, 16)
    counts = rng.integers(1, 4, size=16)
    weighted, repeated = MlpTrainer.from_snapshot(snap, batch_size=16), MlpTrainer.from_snapshot(snap)
    loss_w = weighted.step(obs, act, counts.astype(np.float32))
    loss_r = repeated.step(np.repeat(obs, counts, axis=0), np.repeat(act, counts, axis=0))
    assert loss_w == pytest.approx(loss_r, rel=1e-5)
    for a, b in zip(weighted.weights()[0], repeated.weights()[0], strict=True):
        np.testing.assert_allclose(a, b, atol=2e-6)
    hand = float(np.sum(counts[:, None] * (snap.act(obs) - act) ** 2) / (4 * counts.sum()))
    assert loss_w == pytest.approx(hand, rel=1e-4)


def test_an_ensembles_members_weigh_their_own_rows(rng: np.random.Generator) -> None:
    members = [PolicyNet(15, (130, 72, 40), generator=torch.Generator().manual_seed(s)).snapshot()
               for s in (1, 2)]
    ens = EnsembleSnapshot.of_members(members)
    obs, act = _data(rng, 2 * 8)
    obs, act = obs.reshape(2, 8, 15), act.reshape(2, 8, 4)
    weights = rng.uniform(0.5, 3.0, size=(2, 8)).astype(np.float32)
    trainer = EnsembleTrainer.from_snapshot(ens, batch_size=8)
    trainer.step(obs, act, weights)
    for k, member in enumerate(members):
        alone = MlpTrainer.from_snapshot(member, batch_size=8)
        assert trainer.member_losses[k] == pytest.approx(alone.step(obs[k], act[k], weights[k]), rel=1e-5)
        np.testing.assert_allclose(trainer.weights()[0][0][k], alone.weights()[0][0], atol=2e-6)


def test_equal_weights_are_the_plain_mse(rng: np.random.Generator) -> None:
    snap = PolicyNet(15, (130, 72, 40), generator=torch.Generator().manual_seed(4)).snapshot()
    obs, act = _data(rng, 64)
    assert MlpTrainer.from_snapshot(snap).step(obs, act, np.full(64, 2.5, np.float32)) == pytest.approx(
        MlpTrainer.from_snapshot(snap).step(obs, act), rel=1e-6)
    with pytest.raises(ValueError, match="positive weights"):
        MlpTrainer.from_snapshot(snap).step(obs, act, np.zeros(64, np.float32))


def _mixed_dataset(rng: np.random.Generator) -> HumanDataset:
    """Nine demonstrations and one intervention episode over the same states, the
    intervention with the opposite roll stick."""
    ds = HumanDataset(None)
    obs = rng.normal(size=(60, 15)) * 0.3
    for episode in range(10):
        source = INT if episode == 9 else DEM
        roll = -0.5 if source is INT else 0.5
        ds.extend(Sample(episode, s, 0.0, source, o, (roll, 0, 0, 0)) for s, o in enumerate(obs))
    return ds


def test_the_learner_hands_each_rows_weight_to_the_trainer(rng: np.random.Generator) -> None:
    ds = _mixed_dataset(rng)
    cfg = LearnerConfig(intervention_weight=9.0, takeover_steps=5, takeover_weight=20.0)
    learner = Learner(cfg, ds)
    expected = sample_weights(cfg, ds.view())
    draws = np.random.default_rng(cfg.seed)  # the learner's draws, as with the switch off
    seen: list[np.ndarray | None] = []
    real = learner.trainer.step
    learner.trainer.step = lambda o, a, w=None: (seen.append(w), real(o, a, w))[1]  # type: ignore[method-assign]
    for _ in range(5):
        learner.step()
    for w in seen:
        assert w is not None and w.tolist() == expected[draws.integers(0, len(ds), size=64)].tolist()
    assert set(expected.tolist()) == {1.0, 9.0, 20.0}


def test_weighting_pulls_the_policy_towards_the_interventions(rng: np.random.Generator) -> None:
    ds = _mixed_dataset(rng)
    probe = ds.view().obs[:60]

    def mean_roll(weight: float) -> float:
        learner = Learner(LearnerConfig(intervention_weight=weight, learning_rate=1e-3), ds)
        for _ in range(1500):
            learner.step()
        return float(np.mean(learner.trainer.snapshot().act(probe)[:, 0]))

    # the least-squares stick: 0.9 * 0.5 - 0.1 * 0.5 = 0.4 unweighted; (9 - 9) / 18 * 0.5 = 0 at weight 9
    plain, weighted = mean_roll(1.0), mean_roll(9.0)
    assert abs(plain - 0.4) < 0.05 and abs(weighted) < 0.05, (plain, weighted)


@pytest.mark.parametrize("members", [1, 3])
def test_all_weights_one_trains_bit_identically(rng: np.random.Generator, members: int) -> None:
    ds = _mixed_dataset(rng)
    snaps = []
    for cfg in (LearnerConfig(ensemble_members=members),
                LearnerConfig(ensemble_members=members, intervention_weight=1.0, takeover_steps=7, takeover_weight=1.0)):
        learner = Learner(cfg, ds)
        losses = [learner.step() for _ in range(30)]
        snap = learner.publish()
        snaps.append((losses, [w.tobytes() for w in snap.weights], [b.tobytes() for b in snap.biases]))
    assert snaps[0] == snaps[1]
