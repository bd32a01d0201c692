"""holdout_stop: the held-out share, the session between episodes that stops on the held-out
loss, the averaged weights it publishes, and that with the switch off nothing changes."""

from __future__ import annotations

import numpy as np
import pytest

from companion.config import LearnerConfig
from companion.errors import ConfigError
from companion.learning.dataset import HumanDataset
from companion.learning.learner import Learner
from companion.learning.runners import BudgetedLearner
from companion.learning.stopping import HoldoutSplit, PatienceRule, WeightAverage, holdout_loss
from companion.msg.sample import Sample, Source

MAPPING = np.random.default_rng(7).normal(0, 0.5, size=(4, 15)).astype(np.float32)
FAST = {"learning_rate": 1e-3, "holdout_check_every_updates": 25, "holdout_patience_checks": 4}


def _grow(ds: HumanDataset, rng: np.random.Generator, n: int, episode: int = 0) -> None:
    """Noisy samples of a known mapping; column 0 (north, which a mirror keeps) is the row's
    index, so a minibatch row says which sample it came from."""
    start = len(ds)
    obs = rng.normal(size=(n, 15)).astype(np.float32)
    obs[:, 0] = np.arange(start, start + n)
    act = np.clip(np.tanh(obs @ MAPPING.T) + rng.normal(0, 0.2, size=(n, 4)), -1, 1)
    ds.extend(Sample(episode, i, 0.0, Source.DEMONSTRATION, o, a) for i, (o, a) in enumerate(zip(obs, act, strict=True)))


def _dataset(rng: np.random.Generator, n: int) -> HumanDataset:
    ds = HumanDataset(None)
    _grow(ds, rng, n)
    return ds


def test_the_split_is_fixed_by_the_seed_and_by_row(rng: np.random.Generator) -> None:
    split = HoldoutSplit(0.1, 10, seed=3)
    big = split.held_out(100_000)
    assert np.array_equal(HoldoutSplit(0.1, 10, seed=3).held_out(537), big[:537])  # growing changes no row
    assert not np.array_equal(HoldoutSplit(0.1, 10, seed=4).held_out(100_000), big)
    assert abs(big.mean() - 0.1) < 0.01
    blocks = big.reshape(-1, 10)
    assert np.all(blocks.all(axis=1) | ~blocks.any(axis=1))  # whole blocks of 10
    assert sorted([*split.training_rows(537), *split.held_rows(537)]) == list(range(537))


def test_patience_and_average() -> None:
    rule = PatienceRule(2)
    assert [rule.check(x) for x in (5.0, 4.0, 4.5, 4.0)] == [True, True, False, False]
    assert rule.exhausted and rule.best_check == 1
    avg = WeightAverage(np.zeros(3, np.float32), decay=0.75)
    avg.update(np.full(3, 4.0, np.float32))
    avg.update(np.full(3, 4.0, np.float32))
    assert avg.values.tolist() == [1.75] * 3  # 0 -> 1 -> 1.75


@pytest.mark.parametrize("extra", [{}, {"mirror_augment": True}, {"ensemble_members": 2},
                                   {"intervention_weight": 3.0}])
def test_held_out_samples_are_never_trained_on(rng: np.random.Generator, extra: dict) -> None:
    ds = _dataset(rng, 400)
    learner = Learner(LearnerConfig(holdout_stop=True, **FAST, **extra), ds)
    seen: set[int] = set()
    real = learner.trainer.step

    def spy(obs: np.ndarray, actions: np.ndarray, row_weights: np.ndarray | None = None) -> float:
        seen.update(int(i) for i in obs[..., 0].reshape(-1))
        return real(obs, actions, row_weights)

    learner.trainer.step = spy  # type: ignore[method-assign]
    learner.train_until_converged(budget=300)  # during an episode: the paper's loop
    learner.train_to_holdout_stop(2000)  # between episodes
    _grow(ds, rng, 200, episode=1)
    learner.train_to_holdout_stop(2000)
    held = set(HoldoutSplit(0.1, 10, LearnerConfig().seed).held_rows(len(ds)).tolist())
    assert held and not seen & held
    assert len(seen) > 0.8 * (len(ds) - len(held))


def test_the_session_stops_on_patience_and_publishes_the_best_average(rng: np.random.Generator) -> None:
    ds = _dataset(rng, 600)
    cfg = LearnerConfig(holdout_stop=True, **FAST)
    learner = Learner(cfg, ds)
    split = HoldoutSplit(cfg.holdout_share, cfg.holdout_block_samples, cfg.seed)
    held = split.held_rows(len(ds))
    before = holdout_loss(learner.latest_snapshot, ds.view(), held, None)
    result = learner.train_to_holdout_stop(40_000)
    assert result.stopped_by == "patience" and result.updates < 40_000
    assert result.checks == result.updates // cfg.holdout_check_every_updates + 1  # check 0: the start
    assert result.checks - 1 - result.best_check == cfg.holdout_patience_checks
    snap = learner.latest_snapshot
    assert holdout_loss(snap, ds.view(), held, None) == pytest.approx(result.holdout_loss, rel=1e-6)
    assert result.holdout_loss < 0.7 * before
    assert snap.version == learner.updates == result.updates
    flown = np.concatenate([w.reshape(-1) for w in snap.weights])  # training goes on from what flies
    trained = np.concatenate([w.reshape(-1) for w in learner.trainer.snapshot().weights])
    assert flown.tobytes() == trained.tobytes()


def test_the_cap_ends_a_session_that_keeps_improving(rng: np.random.Generator) -> None:
    ds = _dataset(rng, 300)
    learner = Learner(LearnerConfig(holdout_stop=True, **{**FAST, "holdout_patience_checks": 10_000}), ds)
    result = learner.train_to_holdout_stop(130)
    assert (result.updates, result.stopped_by, result.checks) == (130, "cap", 7)  # 6 x 25 + 5, checks 0-6


def test_between_episodes_runs_once_per_new_data(rng: np.random.Generator) -> None:
    ds = _dataset(rng, 300)
    learner = Learner(LearnerConfig(holdout_stop=True, mode="budgeted", **FAST), ds)
    runner = BudgetedLearner(learner)
    runner.on_control_step()
    assert runner.between_episodes() > 0
    assert runner.between_episodes() == 0  # nothing new
    _grow(ds, rng, 50, episode=1)
    assert runner.between_episodes() > 0


def test_before_any_held_out_row_the_papers_loop_runs(rng: np.random.Generator) -> None:
    cfg = LearnerConfig(holdout_stop=True, holdout_share=0.01, **FAST)
    n = next(n for n in range(10, 2000, 10) if len(HoldoutSplit(0.01, 10, cfg.seed).held_rows(n)) == 0
             and len(HoldoutSplit(0.01, 10, cfg.seed).held_rows(n + 10)) > 0)
    result = Learner(cfg, _dataset(rng, n)).train_to_holdout_stop(500)
    assert result.stopped_by == "no held-out samples" and 0 < result.updates <= 500


def test_nothing_to_train_on_while_every_row_is_held_out(rng: np.random.Generator) -> None:
    seed = next(s for s in range(200) if HoldoutSplit(0.5, 10, s).held_out(10).all())
    learner = Learner(LearnerConfig(holdout_stop=True, holdout_share=0.5, seed=seed), _dataset(rng, 10))
    assert not learner.has_work and not learner.has_unsettled_samples
    with pytest.raises(ValueError, match="all held out"):
        learner.step()
    with pytest.raises(ConfigError, match="holdout_stop"):
        Learner(LearnerConfig(), _dataset(rng, 10)).train_to_holdout_stop(10)


def test_off_between_episodes_trains_as_before(rng: np.random.Generator) -> None:
    """Off (the other holdout keys changed, to no effect): the paper's loop with the same
    draws, bit for bit."""
    ds = _dataset(rng, 300)
    runs = []
    for cfg in (LearnerConfig(mode="budgeted", between_episode_updates=500),
                LearnerConfig(mode="budgeted", between_episode_updates=500, holdout_share=0.5,
                              holdout_patience_checks=1, weight_average_decay=0.5)):
        runner = BudgetedLearner(Learner(cfg, ds))
        runner.on_control_step()
        updates = runner.between_episodes()
        snap = runner.latest_snapshot
        runs.append((updates, snap.version, b"".join(w.tobytes() for w in (*snap.weights, *snap.biases))))
    assert runs[0] == runs[1] and runs[0][0] > 0
