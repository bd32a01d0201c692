"""The immutable policy the control loop flies: NumPy weights and their input normalisation.

``PolicySnapshot`` is a frozen NumPy copy of the network's weights: the control loop calls
``snapshot.act(obs)`` with no torch, no gradients and no locks, and a new snapshot replaces the
old one in a single assignment. This module needs only NumPy, so a flight-only install (no
torch) can load a checkpoint and fly it; the trainable torch network is
:class:`companion.learning.policy.PolicyNet`.

Shape and bounds: ``obs_dim -> hidden... -> 4`` with ReLU between hidden layers and ``tanh`` on
the last layer, so every action is strictly inside [-1, 1] without clipping (the paper's
joystick range). Inputs are normalised, ``(obs - mean) / std``, and the normalisation travels
with the weights (snapshot, checkpoint).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from companion.msg.command import ACT_DIM
from companion.msg.observation import OBS_DIM


def _frozen_f32(a: np.ndarray | Sequence[float]) -> np.ndarray:
    """A private, read-only float32 copy (so no one can mutate a published array)."""
    out = np.array(a, dtype=np.float32, copy=True)
    out.flags.writeable = False
    return out


@dataclass(frozen=True)
class Normalisation:
    """Per-feature input scaling ``(obs - mean) / std`` saved with the model."""

    mean: np.ndarray
    std: np.ndarray

    def __post_init__(self) -> None:
        mean, std = _frozen_f32(self.mean), _frozen_f32(self.std)
        if mean.ndim != 1 or mean.shape != std.shape:
            raise ValueError(f"normalisation mean {mean.shape} and std {std.shape} must be equal 1-D")
        if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(std)) and np.all(std > 0)):
            raise ValueError("normalisation needs finite mean and finite std > 0 for every feature")
        object.__setattr__(self, "mean", mean)
        object.__setattr__(self, "std", std)

    @classmethod
    def identity(cls, dim: int = OBS_DIM) -> Normalisation:
        """No scaling: for observations that are already normalised upstream."""
        return cls(np.zeros(dim, np.float32), np.ones(dim, np.float32))

    @property
    def dim(self) -> int:
        return int(self.mean.shape[0])


@dataclass(frozen=True)
class PolicySnapshot:
    """Immutable policy weights (torch layout: ``weights[i]`` is ``(out, in)``) + normalisation.

    ``version`` counts the learner's updates; ``dataset_size_trained`` is the number of samples
    the dataset held when the last update included in these weights drew its minibatch.
    """

    weights: tuple[np.ndarray, ...]
    biases: tuple[np.ndarray, ...]
    normalisation: Normalisation
    version: int = 0
    dataset_size_trained: int = 0
    _inv_std: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        weights = tuple(_frozen_f32(w) for w in self.weights)
        biases = tuple(_frozen_f32(b) for b in self.biases)
        _check_layers(weights, biases, self.normalisation.dim)
        if self.version < 0 or self.dataset_size_trained < 0:
            raise ValueError("snapshot version and dataset_size_trained must be >= 0")
        object.__setattr__(self, "weights", weights)
        object.__setattr__(self, "biases", biases)
        object.__setattr__(self, "_inv_std", _frozen_f32(1.0 / self.normalisation.std))

    @property
    def obs_dim(self) -> int:
        return int(self.weights[0].shape[1])

    @property
    def hidden(self) -> tuple[int, ...]:
        return tuple(int(w.shape[0]) for w in self.weights[:-1])

    def act(self, obs_vector: np.ndarray) -> np.ndarray:
        """Actions in (-1, 1) for one observation ``(obs_dim,)`` or a batch ``(n, obs_dim)``.

        Pure NumPy, no allocation of shared state: safe to call from any thread. A non-finite
        observation gives non-finite actions; the commands module refuses those.
        """
        x = np.asarray(obs_vector, dtype=np.float32)
        if x.shape[-1] != self.obs_dim:
            raise ValueError(f"observation has {x.shape[-1]} values, the policy expects {self.obs_dim}")
        h = (x - self.normalisation.mean) * self._inv_std
        last = len(self.weights) - 1
        for i, (w, b) in enumerate(zip(self.weights, self.biases, strict=True)):
            h = h @ w.T
            h += b
            if i < last:
                np.maximum(h, 0.0, out=h)
        return np.tanh(h, out=h)


def random_snapshot(obs_dim: int, hidden: Sequence[int], *, init_std: float, seed: int,
                    normalisation: Normalisation | None = None) -> PolicySnapshot:
    """A fresh policy drawn by NumPy: weights ~ N(0, init_std), biases 0 (the network's own
    initialisation, from another generator). The lean runtime's start when torch is absent."""
    rng = np.random.default_rng(seed)
    sizes = [obs_dim, *hidden, ACT_DIM]
    weights = tuple(rng.normal(0.0, init_std, (o, i)).astype(np.float32)
                    for i, o in zip(sizes[:-1], sizes[1:], strict=True))
    biases = tuple(np.zeros(o, np.float32) for o in sizes[1:])
    return PolicySnapshot(weights, biases, normalisation or Normalisation.identity(obs_dim))


def _check_layers(weights: tuple[np.ndarray, ...], biases: tuple[np.ndarray, ...], obs_dim: int) -> None:
    """Refuse layer shapes that do not chain obs_dim -> ... -> ACT_DIM."""
    if not weights or len(weights) != len(biases):
        raise ValueError(f"need as many weight matrices as bias vectors, got {len(weights)}/{len(biases)}")
    width = obs_dim
    for i, (w, b) in enumerate(zip(weights, biases, strict=True)):
        if w.ndim != 2 or w.shape[1] != width or b.shape != (w.shape[0],):
            raise ValueError(f"layer {i}: weight {w.shape} / bias {b.shape} do not take {width} inputs")
        if not (np.isfinite(w.sum()) and np.isfinite(b.sum())):  # one NaN/inf poisons the sum
            raise ValueError(f"layer {i} holds non-finite weights; refusing to fly them")
        width = w.shape[0]
    if width != ACT_DIM:
        raise ValueError(f"the last layer gives {width} outputs, actions need {ACT_DIM}")
