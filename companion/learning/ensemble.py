"""An ensemble of K policies: the mean action to fly, and their disagreement as a score.

The paper's network cannot say when it is unsure. K copies of it (the same 15-130-72-40-4
shape), started from different random weights and each trained on its own minibatches drawn
with replacement (bootstrapped minibatches), agree where the person showed them what to do
and disagree elsewhere: the disagreement is the novelty signal of ThriftyDAgger (Hoque et al.
2021), which asks the person for help when it is high (:mod:`companion.control.ask`).

``EnsembleSnapshot`` is a :class:`PolicySnapshot` (so everything that flies, saves or fits a
snapshot takes it) whose ``act`` is the members' mean action; ``act_with_score`` adds the
score, the members' action variance averaged over the four sticks. Its ``weights``/``biases``
are member 0's, so a reader that knows nothing of ensembles still gets a valid policy.
The K members are computed together: each layer is one stacked ``(K, in, out)`` product, so
flying K members costs a few NumPy calls more than one (bench/ensemble.py).

``EnsembleTrainer`` is :class:`~companion.learning.trainer.MlpTrainer` with a leading member
axis on every buffer: one update of all K members is the same number of NumPy calls as one
update of one member, each member with its own minibatch, MSE and RMSprop state.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from itertools import pairwise
from typing import Any

import numpy as np

from companion.learning.snapshot import Normalisation, PolicySnapshot, _frozen_f32
from companion.learning.trainer import TrainerStep

F32 = np.float32
DEFAULT_MEMBERS = 5


@dataclass(frozen=True)
class EnsembleSnapshot(PolicySnapshot):
    """K policies of one shape; flies their mean action. ``member_weights[i]`` is layer i of
    every member stacked, ``(K, out, in)``; ``member_biases[i]`` is ``(K, out)``."""

    member_weights: tuple[np.ndarray, ...] = ()
    member_biases: tuple[np.ndarray, ...] = ()
    _wt: tuple[np.ndarray, ...] = field(init=False, repr=False, compare=False)
    _b3: tuple[np.ndarray, ...] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        super().__post_init__()
        ws = tuple(_frozen_f32(w) for w in self.member_weights)
        bs = tuple(_frozen_f32(b) for b in self.member_biases)
        if len(ws) != len(self.weights) or len(bs) != len(self.biases):
            raise ValueError(f"an ensemble needs stacked weights for all {len(self.weights)} layers")
        k = ws[0].shape[0] if ws and ws[0].ndim == 3 else 0
        for i, (w, b, w0, b0) in enumerate(zip(ws, bs, self.weights, self.biases, strict=True)):
            if w.shape != (k, *w0.shape) or b.shape != (k, *b0.shape) or k < 1:
                raise ValueError(f"layer {i}: stacked weight {w.shape} / bias {b.shape} are not K copies "
                                 f"of {w0.shape} / {b0.shape}")
            if not (np.isfinite(w.sum()) and np.isfinite(b.sum())):
                raise ValueError(f"layer {i} of the ensemble holds non-finite weights; refusing to fly them")
        object.__setattr__(self, "member_weights", ws)
        object.__setattr__(self, "member_biases", bs)
        object.__setattr__(self, "_wt", tuple(np.ascontiguousarray(w.transpose(0, 2, 1)) for w in ws))
        object.__setattr__(self, "_b3", tuple(b[:, None, :] for b in bs))

    @classmethod
    def stack(cls, weights: Sequence[np.ndarray], biases: Sequence[np.ndarray], normalisation: Normalisation,
              version: int = 0, dataset_size_trained: int = 0) -> EnsembleSnapshot:
        """From per-layer stacks ``(K, out, in)`` and ``(K, out)`` (member 0 doubles as the plain policy)."""
        return cls(tuple(w[0] for w in weights), tuple(b[0] for b in biases), normalisation, version,
                   dataset_size_trained, tuple(weights), tuple(biases))

    @classmethod
    def of_members(cls, members: Sequence[PolicySnapshot], version: int = 0,
                   dataset_size_trained: int = 0) -> EnsembleSnapshot:
        """The ensemble of separate snapshots of one shape (the first one's normalisation)."""
        if not members:
            raise ValueError("an ensemble needs at least one member")
        layers = range(len(members[0].weights))
        return cls.stack([np.stack([m.weights[i] for m in members]) for i in layers],
                         [np.stack([m.biases[i] for m in members]) for i in layers],
                         members[0].normalisation, version, dataset_size_trained)

    @property
    def members(self) -> int:
        return int(self.member_weights[0].shape[0])

    def member(self, k: int) -> PolicySnapshot:
        """Member ``k`` alone, as a plain snapshot."""
        return PolicySnapshot(tuple(w[k] for w in self.member_weights), tuple(b[k] for b in self.member_biases),
                              self.normalisation, self.version, self.dataset_size_trained)

    def member_actions(self, obs_vector: np.ndarray) -> np.ndarray:
        """Every member's actions: ``(K, 4)`` for one observation, ``(K, n, 4)`` for ``n``."""
        x = np.asarray(obs_vector, dtype=np.float32)
        if x.shape[-1] != self.obs_dim:
            raise ValueError(f"observation has {x.shape[-1]} values, the policy expects {self.obs_dim}")
        single = x.ndim == 1
        h = ((x - self.normalisation.mean) * self._inv_std).reshape(-1, self.obs_dim)
        last = len(self._wt) - 1
        for i, (wt, b) in enumerate(zip(self._wt, self._b3, strict=True)):
            h = np.matmul(h, wt)  # (n, in) or (K, n, in) @ (K, in, out) -> (K, n, out)
            h += b
            if i < last:
                np.maximum(h, 0.0, out=h)
        np.tanh(h, out=h)
        return h[:, 0, :] if single else h

    def act(self, obs_vector: np.ndarray) -> np.ndarray:
        """The members' mean action (in (-1, 1)), for one observation or a batch."""
        return self.member_actions(obs_vector).mean(axis=0)

    def act_with_score(self, obs_vector: np.ndarray) -> tuple[np.ndarray, np.ndarray | float]:
        """(mean action, disagreement): the members' action variance, averaged over the sticks
        (a float for one observation, ``(n,)`` for a batch)."""
        a = self.member_actions(obs_vector)
        score = a.var(axis=0).mean(axis=-1)
        return a.mean(axis=0), float(score) if score.ndim == 0 else score

    def scores(self, obs_batch: np.ndarray, chunk: int = 4096) -> np.ndarray:
        """Disagreement on every row of ``(n, obs_dim)`` (chunked: bounded memory)."""
        obs = np.asarray(obs_batch, dtype=np.float32).reshape(-1, self.obs_dim)
        out = np.empty(len(obs), np.float32)
        for s in range(0, len(obs), chunk):
            out[s:s + chunk] = self.member_actions(obs[s:s + chunk]).var(axis=0).mean(axis=-1)
        return out


def disagreement(snapshot: PolicySnapshot, obs_vector: np.ndarray) -> tuple[np.ndarray, float]:
    """(action, score) of any snapshot: an ensemble's disagreement, NaN for a single policy."""
    if isinstance(snapshot, EnsembleSnapshot):
        action, score = snapshot.act_with_score(obs_vector)
        return action, float(score)
    return snapshot.act(obs_vector), math.nan


class EnsembleTrainer(TrainerStep):
    """K MLPs + their RMSprop states as stacked float32 buffers; ``step()`` updates all K.

    The arithmetic of :class:`~companion.learning.trainer.MlpTrainer` member by member (a test
    checks it against K separate trainers): each member's loss is the MSE over its own
    minibatch, and each has its own square averages.
    """

    def __init__(self, weights: Sequence[np.ndarray], biases: Sequence[np.ndarray], mean: np.ndarray,
                 std: np.ndarray, *, lr: float = 1e-4, alpha: float = 0.99, eps: float = 1e-8,
                 batch_size: int = 64) -> None:
        k = int(np.shape(weights[0])[0])
        sizes = [int(np.shape(weights[0])[2])] + [int(np.shape(w)[1]) for w in weights]
        if k < 1 or len(weights) != len(biases) or any(
                np.shape(w) != (k, o, i) or np.shape(b) != (k, o)
                for w, b, i, o in zip(weights, biases, sizes[:-1], sizes[1:], strict=True)):
            raise ValueError("stacked weights (K, out, in) and biases (K, out) must chain layer to layer")
        total = k * sum((i + 1) * o for i, o in pairwise(sizes))
        self._p, self._g, self._sq, self._den, self._num = (np.zeros(total, F32) for _ in range(5))
        self._A: list[np.ndarray] = []
        self._gA: list[np.ndarray] = []
        off = 0
        for i, o in pairwise(sizes):
            n = k * (i + 1) * o
            self._A.append(self._p[off:off + n].reshape(k, i + 1, o))
            self._gA.append(self._g[off:off + n].reshape(k, i + 1, o))
            off += n
        for a, w, b in zip(self._A, weights, biases, strict=True):
            a[:, :-1] = np.asarray(w, F32).transpose(0, 2, 1)
            a[:, -1] = b
        self._AwT = [a[:, :-1].transpose(0, 2, 1) for a in self._A]
        self.mean, self.std = np.array(mean, F32), np.array(std, F32)
        self.lr, self.alpha, self.eps = lr, alpha, eps
        self._c = (F32(alpha), F32(1 - alpha), F32(eps), F32(-lr))
        self.updates = 0
        self.members = k
        self.sizes = tuple(sizes)
        self.member_losses = np.full(k, np.nan, F32)
        self._alloc(batch_size)

    def _alloc(self, n: int) -> None:
        s, k = self.sizes, self.members
        self._xa = [np.ones((k, n, w + 1), F32) for w in s[:-1]]
        self._xv = [xa[..., :-1] for xa in self._xa]
        self._dz = [np.empty((k, n, w), F32) for w in s[1:]]
        self._mask = [np.empty((k, n, w), F32) for w in s[1:]]
        self._raw, self._y, self._diff = (np.empty((k, n, w), F32) for w in (s[0], s[-1], s[-1]))
        self._norm = F32(2.0 / (n * s[-1]))

    def step(self, obs_batch: np.ndarray, target_batch: np.ndarray,
             row_weights: np.ndarray | None = None) -> float:
        """One RMSprop update of every member on its own rows ``(K, n, in)`` / ``(K, n, 4)``;
        returns the members' mean MSE before the update (each is in ``member_losses``).

        ``row_weights`` ``(K, n)`` (None: all equal) make each member's loss the weighted mean
        of its rows' squared errors (:func:`~companion.learning.trainer.root_weights`).
        Raises FloatingPointError on a non-finite loss, leaving weights and state untouched.
        """
        if obs_batch.shape[:2] != self._raw.shape[:2]:
            if obs_batch.shape[0] == self.members:
                self._alloc(obs_batch.shape[1])
        y, diff, root = self._residual(obs_batch, target_batch, row_weights)  # as MlpTrainer.step
        losses = np.einsum("knj,knj->k", diff, diff) / F32(diff[0].size)
        if not np.all(np.isfinite(losses)):
            raise FloatingPointError(f"training loss became {losses.tolist()} at update {self.updates + 1}")
        self._update(y, diff, root)
        self.member_losses = losses.astype(F32)
        return float(losses.mean())

    def weights(self) -> tuple[tuple[np.ndarray, ...], tuple[np.ndarray, ...]]:
        """Copies of the stacks ``(K, out, in)`` and ``(K, out)``, layer by layer."""
        return (tuple(a[:, :-1].transpose(0, 2, 1).copy() for a in self._A),
                tuple(a[:, -1].copy() for a in self._A))

    @classmethod
    def from_snapshot(cls, snap: EnsembleSnapshot, **kw: Any) -> EnsembleTrainer:
        return cls(snap.member_weights, snap.member_biases, snap.normalisation.mean, snap.normalisation.std, **kw)

    def snapshot(self, version: int = 0, dataset_size_trained: int = 0) -> EnsembleSnapshot:
        ws, bs = self.weights()
        return EnsembleSnapshot.stack(ws, bs, Normalisation(self.mean, self.std), version, dataset_size_trained)

