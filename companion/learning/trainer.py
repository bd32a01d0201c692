"""The learner's update: the policy MLP's forward, MSE loss, backward and RMSprop in NumPy.

Computes what ``PolicyNet`` + ``F.mse_loss`` + ``torch.optim.RMSprop`` (no momentum, not
centred, no weight decay) compute, up to float32 round-off: forward ``(obs - mean) / std``
-> ReLU hidden layers -> ``tanh``; loss = mean over all ``batch x actions`` elements of the
squared error; ``sq = alpha*sq + (1-alpha)*g*g``, ``p -= lr*g / (sqrt(sq) + eps)`` in torch's
operation order. The normalisation is fixed (a buffer in torch): it is never trained. One
update agrees with torch to round-off; over hundreds, two float32 runs can drift apart when a
ReLU input sits within round-off of 0 (torch float64 against float32 drifts the same way).

Why NumPy: a minibatch-64 update of this small network is mostly per-call overhead, about
1 us per NumPy call against 2-4 us per torch call; this runs about 4x as many updates per
second as autograd + torch.optim (bench/learner.py).

Layout: layer ``k`` is one matrix ``A_k = [[W_k.T], [b_k]]`` of shape ``(in+1, out)`` and
every layer input carries a trailing column of ones, so the bias rides inside the matrix
product. All ``A_k`` live in one flat buffer, as do their gradients and RMSprop state, so the
optimiser is nine whole-buffer NumPy calls; a step allocates nothing.

NumPy's BLAS starts as many threads as cores: on a busy 2-core machine a threaded 64x130x72
product is about 10x *slower* than a single-threaded one, so the learner runs its updates
under ``threadpoolctl.threadpool_limits(1)`` (:func:`one_blas_thread`).
"""

from __future__ import annotations

import math
import sys
from collections.abc import Sequence
from itertools import pairwise
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

from companion.learning.snapshot import Normalisation, PolicySnapshot

F32 = np.float32


def forward_into(obs: np.ndarray, mean: np.ndarray, std: np.ndarray, raw: np.ndarray,
                 xa: Sequence[np.ndarray], xv: Sequence[np.ndarray], A: Sequence[np.ndarray],
                 y_out: np.ndarray) -> np.ndarray:
    """The forward pass into preallocated buffers (one network, or K stacked along a first
    axis): normalise, then ReLU layers, then tanh. ``xa[k]`` are the layer inputs with their
    bias column, ``xv[k]`` views of them without it; returns ``y_out``."""
    np.subtract(obs, mean, out=raw)
    np.divide(raw, std, out=xv[0])
    last = len(A) - 1
    zero = F32(0)
    for k in range(last):
        np.matmul(xa[k], A[k], out=xv[k + 1])
        np.maximum(xv[k + 1], zero, out=xv[k + 1])
    np.matmul(xa[last], A[last], out=y_out)
    np.tanh(y_out, out=y_out)
    return y_out


class RmsPropState:
    """RMSprop's state of a trainer (square averages ``_sq``, step count ``updates``): what
    another process needs to go on; and the flat parameter buffer ``_p`` it updates with the
    flat gradient ``_g``. Shared by the single network and the ensemble."""

    _p: np.ndarray
    _g: np.ndarray
    _sq: np.ndarray
    _den: np.ndarray
    _num: np.ndarray
    _c: tuple[np.float32, np.float32, np.float32, np.float32]  # alpha, 1 - alpha, eps, -lr
    updates: int

    def _rmsprop(self) -> None:
        alpha, one_m_alpha, eps, neg_lr = self._c
        sq, g, den, num = self._sq, self._g, self._den, self._num
        np.multiply(sq, alpha, out=sq)  # sq.mul_(alpha).addcmul_(g, g, value=1-alpha)
        np.multiply(g, one_m_alpha, out=num)
        np.multiply(num, g, out=num)
        np.add(sq, num, out=sq)
        np.sqrt(sq, out=den)  # den = sq.sqrt().add_(eps)
        np.add(den, eps, out=den)
        np.multiply(g, neg_lr, out=num)  # p.addcdiv_(g, den, value=-lr)
        np.divide(num, den, out=num)
        np.add(self._p, num, out=self._p)

    def flat_parameters(self) -> np.ndarray:
        """Every weight and bias in one read-only float32 view: it changes with every update
        (copy it to keep it)."""
        view = self._p.view()
        view.flags.writeable = False
        return view

    def load_flat_parameters(self, params: np.ndarray) -> None:
        """Set every weight and bias from :meth:`flat_parameters` of a trainer of this shape
        (the optimiser's state stays)."""
        if np.shape(params) != self._p.shape:
            raise ValueError(f"{np.shape(params)} parameters, this trainer has {self._p.shape}")
        self._p[:] = params

    def state(self) -> dict[str, Any]:
        return {"square_avg": self._sq.copy(), "updates": self.updates}

    def load_state(self, state: dict[str, Any]) -> None:
        """Take over :meth:`state` of a trainer of the same shape."""
        sq = np.asarray(state["square_avg"], F32)
        if sq.shape != self._sq.shape:
            raise ValueError(f"optimiser state of {sq.shape[0]} values, this trainer has {self._sq.shape[0]}")
        self._sq[:] = sq
        self.updates = int(state["updates"])


class TrainerStep(RmsPropState):
    """One update's arithmetic on a trainer's preallocated buffers, shared by :class:`MlpTrainer`
    and the ensemble's trainer: their buffers differ only by the ensemble's leading member axis.
    The forward pass, the (weighted) residual, the backward pass and RMSprop are the same NumPy
    calls for both; each trainer sizes its buffers and reduces its own loss."""

    mean: np.ndarray
    std: np.ndarray
    _A: list[np.ndarray]
    _gA: list[np.ndarray]
    _AwT: list[np.ndarray]
    _xa: list[np.ndarray]
    _xv: list[np.ndarray]
    _dz: list[np.ndarray]
    _mask: list[np.ndarray]
    _raw: np.ndarray
    _y: np.ndarray
    _diff: np.ndarray
    _norm: np.float32
    huber_delta: float = 0.0
    """0: the squared error's gradient (the paper's MSE). > 0: Huber's, each element's error capped
    at this many stick units in the gradient, so a few far-off labels (a person's lapse, a slip of
    the hand) pull the fit no harder than an error of delta; below delta it is the MSE's."""

    def _residual(self, obs_batch: np.ndarray, target_batch: np.ndarray,
                  row_weights: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """``(y, diff, root)``: the network's output on ``obs_batch``, ``sqrt(w) (y - t)`` (``y - t``
        without ``row_weights``: its squares are the weighted errors) and ``sqrt(w)`` (None)."""
        if obs_batch.shape != self._raw.shape or target_batch.shape != self._y.shape:
            raise ValueError(f"need obs {self._raw.shape} and targets {self._y.shape}, got "
                             f"{obs_batch.shape} and {target_batch.shape}")
        y = forward_into(obs_batch, self.mean, self.std, self._raw, self._xa, self._xv, self._A, self._y)
        diff = np.subtract(y, target_batch, out=self._diff)
        root = None if row_weights is None else root_weights(row_weights, obs_batch.shape[:-1])
        if root is not None:
            np.multiply(diff, root, out=diff)  # sqrt(w) (y - t): its squares are the weighted errors
        return y, diff, root

    def _update(self, y: np.ndarray, diff: np.ndarray, root: np.ndarray | None) -> None:
        """Backpropagate the residual of :meth:`_residual` into ``_gA`` and take one RMSprop step."""
        xa, xv, dz, mask, zero = self._xa, self._xv, self._dz, self._mask, F32(0)
        last = len(self._A) - 1
        if self.huber_delta > 0:
            self._cap_residual(diff, root)
        if root is not None:
            np.multiply(diff, root, out=diff)  # w (y - t): the weighted loss's gradient
        np.multiply(y, y, out=mask[last])  # tanh' = 1 - y^2
        np.subtract(1, mask[last], out=mask[last])
        np.multiply(diff, self._norm, out=dz[last])
        np.multiply(dz[last], mask[last], out=dz[last])
        for k in range(last, -1, -1):
            np.matmul(xa[k].swapaxes(-1, -2), dz[k], out=self._gA[k])  # [dW.T; db] in one GEMM
            if k:
                np.matmul(dz[k], self._AwT[k], out=dz[k - 1])
                np.greater(xv[k], zero, out=mask[k - 1])  # ReLU' from its output
                np.multiply(dz[k - 1], mask[k - 1], out=dz[k - 1])
        self._rmsprop()
        self.updates += 1

    def _cap_residual(self, diff: np.ndarray, root: np.ndarray | None) -> None:
        """``diff`` (``sqrt(w) (y - t)``, or ``y - t``) with each ``y - t`` capped at ``huber_delta``:
        the Huber loss's gradient, weighted as before (``sqrt(w) > 0`` scales the cap alike)."""
        bound = F32(self.huber_delta) if root is None else root * F32(self.huber_delta)
        np.clip(diff, -bound, bound, out=diff)


class MlpTrainer(TrainerStep):
    """MLP weights + RMSprop state as float32 NumPy buffers; ``step()`` is one update."""

    def __init__(self, weights: Sequence[np.ndarray], biases: Sequence[np.ndarray],
                 mean: np.ndarray, std: np.ndarray, *, lr: float = 1e-4, alpha: float = 0.99,
                 eps: float = 1e-8, batch_size: int = 64) -> None:
        sizes = [int(np.shape(weights[0])[1])] + [int(np.shape(w)[0]) for w in weights]
        if len(weights) != len(biases) or any(
                np.shape(w) != (o, i) or np.shape(b) != (o,)
                for w, b, i, o in zip(weights, biases, sizes[:-1], sizes[1:], strict=True)):
            raise ValueError("weights (out, in) and biases (out,) must chain layer to layer")
        total = sum((i + 1) * o for i, o in pairwise(sizes))
        self._p, self._g, self._sq, self._den, self._num = (np.zeros(total, F32) for _ in range(5))
        self._A: list[np.ndarray] = []
        self._gA: list[np.ndarray] = []
        self._sqA: list[np.ndarray] = []
        off = 0
        for i, o in pairwise(sizes):
            for flat, views in ((self._p, self._A), (self._g, self._gA), (self._sq, self._sqA)):
                views.append(flat[off:off + (i + 1) * o].reshape(i + 1, o))
            off += (i + 1) * o
        for a, w, b in zip(self._A, weights, biases):
            a[:-1] = np.asarray(w, F32).T
            a[-1] = b
        self._AwT = [a[:-1].T for a in self._A]  # W (out, in) views for dX = dZ @ W
        self.mean, self.std = np.array(mean, F32), np.array(std, F32)
        self.lr, self.alpha, self.eps = lr, alpha, eps
        self._c = (F32(alpha), F32(1 - alpha), F32(eps), F32(-lr))  # torch casts them alike
        self.updates = 0  # RMSprop's step count
        self.sizes = tuple(sizes)
        self._alloc(batch_size)

    def _alloc(self, n: int) -> None:
        s = self.sizes
        self._xa = [np.ones((n, k + 1), F32) for k in s[:-1]]  # layer inputs + ones column
        self._xv = [xa[:, :-1] for xa in self._xa]
        self._dz = [np.empty((n, k), F32) for k in s[1:]]  # dLoss/d(pre-activation)
        self._mask = [np.empty((n, k), F32) for k in s[1:]]
        self._raw, self._y, self._diff = (np.empty((n, k), F32) for k in (s[0], s[-1], s[-1]))
        self._flat_diff = self._diff.reshape(-1)
        self._norm = F32(2.0 / (n * s[-1]))  # d mean((y-t)^2) / dy = 2 (y-t) / numel

    def step(self, obs_batch: np.ndarray, target_batch: np.ndarray,
             row_weights: np.ndarray | None = None) -> float:
        """One RMSprop update on ``(obs, target)`` rows; returns the MSE before the update.

        ``row_weights`` (one per row; None: all equal) make it the weighted mean of the rows'
        squared errors (:func:`root_weights`). With ``huber_delta`` the update follows Huber's
        gradient; the loss returned is still the (weighted) MSE, so ``loss_threshold`` keeps its
        meaning. Raises FloatingPointError on a non-finite loss, leaving weights and state untouched.
        """
        if obs_batch.shape[0] != self._raw.shape[0]:
            self._alloc(obs_batch.shape[0])
        y, diff, root = self._residual(obs_batch, target_batch, row_weights)
        loss = float(np.dot(self._flat_diff, self._flat_diff) / F32(diff.size))
        if not math.isfinite(loss):
            raise FloatingPointError(f"training loss became {loss} at update {self.updates + 1}")
        self._update(y, diff, root)
        return loss

    # -- interop with the project's torch model, optimiser and snapshots -----------------------
    def weights(self) -> tuple[tuple[np.ndarray, ...], tuple[np.ndarray, ...]]:
        """Copies of ``(weights (out, in), biases (out,))`` in PolicyNet's layer order."""
        return tuple(a[:-1].T.copy() for a in self._A), tuple(a[-1].copy() for a in self._A)

    def square_avgs(self) -> list[np.ndarray]:
        """RMSprop's ``square_avg`` in ``PolicyNet.parameters()`` order (W0, b0, W1, ...)."""
        return [x for s in self._sqA for x in (s[:-1].T.copy(), s[-1].copy())]

    def load_square_avgs(self, avgs: Sequence[np.ndarray], updates: int) -> None:
        """Set RMSprop's state from per-parameter arrays in :meth:`square_avgs`' order (as
        ``torch.optim.RMSprop`` keeps them), e.g. to continue a torch optimiser's run."""
        if len(avgs) != 2 * len(self._sqA):
            raise ValueError(f"need {2 * len(self._sqA)} arrays (W0, b0, W1, ...), got {len(avgs)}")
        for k, sq in enumerate(self._sqA):
            sq[:-1] = np.asarray(avgs[2 * k], F32).T
            sq[-1] = avgs[2 * k + 1]
        self.updates = int(updates)

    @classmethod
    def from_snapshot(cls, snap: PolicySnapshot, **kw: Any) -> MlpTrainer:
        """Weights and normalisation of a snapshot (hyper-parameters: keyword arguments)."""
        return cls(snap.weights, snap.biases, snap.normalisation.mean, snap.normalisation.std, **kw)

    def snapshot(self, version: int = 0, dataset_size_trained: int = 0) -> PolicySnapshot:
        """A frozen PolicySnapshot of the current weights (what the control loop flies)."""
        ws, bs = self.weights()
        return PolicySnapshot(ws, bs, Normalisation(self.mean, self.std), version, dataset_size_trained)



def root_weights(row_weights: np.ndarray, rows_shape: tuple[int, ...]) -> np.ndarray:
    """``sqrt(w / mean(w))`` per row as a column ``(..., n, 1)`` (float32): the weights scaled to
    a mean of 1 over each minibatch (each ensemble member's), so the weighted loss of equal
    weights is the plain MSE and keeps the loss threshold's meaning."""
    w = np.asarray(row_weights, np.float32)
    if w.shape != rows_shape or not np.all(w > 0):
        raise ValueError(f"need positive weights of shape {rows_shape}, got {w.shape}")
    return np.sqrt(w / w.mean(axis=-1, keepdims=True))[..., None]


def one_blas_thread() -> Any:
    """A context in which NumPy's matrix products run on one thread (see the module docstring)."""
    return threadpool_limits(1, user_api="blas")


def limit_torch_threads(n: int) -> None:
    """Cap torch's intra-op threads where torch is loaded; the NumPy trainer needs no torch, so
    a flight-only install (or a process that never imported it) has nothing to cap."""
    torch = sys.modules.get("torch")
    if torch is not None:
        torch.set_num_threads(n)
