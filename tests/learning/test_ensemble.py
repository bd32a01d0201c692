"""The ensemble: K networks trained side by side, their mean action and their disagreement."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from companion.config import LearnerConfig
from companion.errors import ConfigError
from companion.learning.checkpoint import load_checkpoint, save_checkpoint
from companion.learning.dataset import HumanDataset
from companion.learning.ensemble import EnsembleSnapshot, EnsembleTrainer, disagreement
from companion.learning.learner import Learner
from companion.learning.policy import Normalisation
from companion.learning.trainer import MlpTrainer
from companion.msg.sample import Sample, Source

MAPPING = np.random.default_rng(7).normal(0, 0.4, size=(4, 15)).astype(np.float32)


def _dataset(obs: np.ndarray) -> HumanDataset:
    ds = HumanDataset(None)
    acts = (0.5 * np.tanh(obs @ MAPPING.T)).astype(np.float32)  # inside the sticks' range, like a pilot's
    ds.extend(Sample(0, i, 0.0, Source.DEMONSTRATION, o, a) for i, (o, a) in enumerate(zip(obs, acts, strict=True)))
    return ds


def _members(k: int, rng: np.random.Generator) -> tuple[list[np.ndarray], list[np.ndarray]]:
    sizes = (15, 130, 72, 40, 4)
    ws = [rng.normal(0, 0.1, (k, o, i)).astype(np.float32) for i, o in zip(sizes[:-1], sizes[1:], strict=True)]
    bs = [rng.normal(0, 0.01, (k, o)).astype(np.float32) for o in sizes[1:]]
    return ws, bs


def test_one_stacked_update_is_k_separate_updates(rng: np.random.Generator) -> None:
    k = 3
    ws, bs = _members(k, rng)
    mean, std = rng.normal(size=15).astype(np.float32), rng.uniform(0.5, 2, 15).astype(np.float32)
    stacked = EnsembleTrainer(ws, bs, mean, std, lr=1e-3)
    alone = [MlpTrainer([w[m] for w in ws], [b[m] for b in bs], mean, std, lr=1e-3) for m in range(k)]
    for _ in range(20):
        obs = rng.normal(size=(k, 64, 15)).astype(np.float32)
        act = np.tanh(rng.normal(size=(k, 64, 4))).astype(np.float32)
        loss = stacked.step(obs, act)
        losses = [t.step(obs[m], act[m]) for m, t in enumerate(alone)]
        assert loss == pytest.approx(np.mean(losses), rel=1e-5)
        np.testing.assert_allclose(stacked.member_losses, losses, rtol=1e-5)
    sw, sb = stacked.weights()
    for m, t in enumerate(alone):
        tw, tb = t.weights()
        for a, b in zip([w[m] for w in sw] + [b[m] for b in sb], list(tw) + list(tb), strict=True):
            np.testing.assert_allclose(a, b, atol=2e-6)


def test_snapshot_flies_the_mean_and_scores_single_and_batch_alike(rng: np.random.Generator) -> None:
    ws, bs = _members(5, rng)
    snap = EnsembleSnapshot.stack(ws, bs, Normalisation.identity())
    obs = rng.normal(size=(7, 15)).astype(np.float32)
    each = np.stack([snap.member(m).act(obs) for m in range(5)])
    np.testing.assert_allclose(snap.act(obs), each.mean(0), atol=1e-6)
    mean, score = snap.act_with_score(obs[2])
    np.testing.assert_allclose(mean, each[:, 2].mean(0), atol=1e-6)
    assert score == pytest.approx(float(each[:, 2].var(0).mean()), rel=1e-4)
    np.testing.assert_allclose(snap.scores(obs), each.var(0).mean(-1), rtol=1e-4)
    assert snap.weights[0] is not None and np.array_equal(snap.weights[0], ws[0][0])  # member 0 as a plain policy
    assert np.isnan(disagreement(snap.member(0), obs[0])[1])


def test_disagreement_is_low_on_training_states_and_high_far_from_them(rng: np.random.Generator) -> None:
    """The constructed case: train on a cloud of states (std 0.5), score states of a cloud six
    times as wide (std 3): where nobody showed the members what to do, they extrapolate apart."""
    train = (0.5 * rng.normal(size=(600, 15))).astype(np.float32)
    cfg = LearnerConfig(ensemble_members=5, learning_rate=1e-3, max_updates=1000, loss_threshold=1e-5, seed=3)
    learner = Learner(cfg, _dataset(train), normalisation=Normalisation.identity())
    result = learner.train_until_converged()
    snap = learner.latest_snapshot
    assert isinstance(snap, EnsembleSnapshot) and snap.members == 5
    assert result.loss < 0.002
    near = (0.5 * rng.normal(size=(300, 15))).astype(np.float32)  # unseen, but from the same cloud
    far = (3.0 * rng.normal(size=(300, 15))).astype(np.float32)
    on, fresh, off = snap.scores(train), snap.scores(near), snap.scores(far)
    print("median scores: train", np.median(on), "unseen near", np.median(fresh), "far", np.median(off))
    assert np.median(off) > 10 * np.median(on), (np.median(on), np.median(off))
    assert np.median(off) > 5 * np.median(fresh), (np.median(fresh), np.median(off))
    threshold = np.quantile(on, 0.98)  # the request rule's threshold at a 2 % target rate
    assert np.mean(off > threshold) > 0.9


def test_members_differ_from_the_start_and_train_on_their_own_minibatches(rng: np.random.Generator) -> None:
    cfg = LearnerConfig(ensemble_members=4, seed=11)
    learner = Learner(cfg, _dataset(rng.normal(size=(200, 15)).astype(np.float32)))
    first = learner.latest_snapshot
    assert isinstance(first, EnsembleSnapshot)
    assert not np.allclose(first.member_weights[0][0], first.member_weights[0][1])
    learner.step()
    again = Learner(cfg, learner.dataset)
    again.step()  # same seed, same draws: the same update
    np.testing.assert_array_equal(learner.publish().member_weights[1], again.publish().member_weights[1])


def test_an_ensemble_checkpoint_round_trips_and_resumes(tmp_path: Path, rng: np.random.Generator) -> None:
    cfg = LearnerConfig(ensemble_members=3)
    learner = Learner(cfg, _dataset(rng.normal(size=(100, 15)).astype(np.float32)))
    learner.train_until_converged(budget=5)
    snap = learner.publish()
    path = save_checkpoint(tmp_path / "e.npz", snap, cfg, dataset_size=100, episode=0, condition="col")
    loaded, _ = load_checkpoint(path)
    assert isinstance(loaded, EnsembleSnapshot) and loaded.members == 3
    obs = rng.normal(size=(4, 15)).astype(np.float32)
    np.testing.assert_array_equal(loaded.act(obs), snap.act(obs))
    resumed = Learner(cfg, learner.dataset, initial=loaded)
    np.testing.assert_array_equal(resumed.latest_snapshot.act(obs), snap.act(obs))
    with pytest.raises(ConfigError, match="member"):
        Learner(LearnerConfig(ensemble_members=5), learner.dataset, initial=loaded)
