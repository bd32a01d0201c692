"""The policy: a small fully connected network and the immutable snapshot the control loop flies.

``PolicyNet`` is what the learner trains (torch). ``PolicySnapshot`` is a frozen NumPy copy of
its weights: the control loop calls ``snapshot.act(obs)`` with no torch, no gradients and no
locks, and a new snapshot replaces the old one in a single assignment.

Shape and bounds: ``obs_dim -> hidden... -> 4`` with ReLU between hidden layers and ``tanh`` on
the last layer, so every action is strictly inside [-1, 1] without clipping (the paper's
joystick range). Inputs are normalised inside the model, ``(obs - mean) / std``, and the
normalisation travels with the weights (snapshot, checkpoint).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import cast

import numpy as np
import torch
from torch import nn

from companion.vision.observation import OBS_DIM

ACTION_NAMES: tuple[str, ...] = ("roll", "pitch", "yaw", "throttle")
ACT_DIM = len(ACTION_NAMES)


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


class PolicyNet(nn.Module):
    """obs -> ReLU hidden layers -> tanh; weights ~ N(0, init_std), biases 0."""

    obs_mean: torch.Tensor
    obs_std: torch.Tensor

    def __init__(
        self,
        obs_dim: int = OBS_DIM,
        hidden: Sequence[int] = (130, 72, 40),
        *,
        init_std: float = 0.1,
        generator: torch.Generator | None = None,
        normalisation: Normalisation | None = None,
    ) -> None:
        super().__init__()
        norm = normalisation or Normalisation.identity(obs_dim)
        if norm.dim != obs_dim:
            raise ValueError(f"normalisation has {norm.dim} features, the policy {obs_dim}")
        sizes = [obs_dim, *hidden, ACT_DIM]
        self.layers = nn.ModuleList(
            torch.nn.utils.skip_init(nn.Linear, a, b) for a, b in zip(sizes[:-1], sizes[1:], strict=True)
        )
        with torch.no_grad():
            for layer in self.linears:
                layer.weight.normal_(0.0, init_std, generator=generator)
                layer.bias.zero_()
        self._norm = norm
        self.register_buffer("obs_mean", torch.from_numpy(norm.mean.copy()))
        self.register_buffer("obs_std", torch.from_numpy(norm.std.copy()))

    @property
    def linears(self) -> list[nn.Linear]:
        return [cast(nn.Linear, layer) for layer in self.layers]

    @property
    def obs_dim(self) -> int:
        return self.linears[0].in_features

    @property
    def hidden(self) -> tuple[int, ...]:
        return tuple(layer.out_features for layer in self.linears[:-1])

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        h = (obs - self.obs_mean) / self.obs_std
        *hidden, last = self.linears
        for layer in hidden:
            h = torch.relu(layer(h))
        return torch.tanh(last(h))

    def normalisation(self) -> Normalisation:
        """The fixed input scaling (set at construction, never trained)."""
        return self._norm

    def snapshot(self, version: int = 0, dataset_size_trained: int = 0) -> PolicySnapshot:
        """A frozen NumPy copy of the current weights (about 30 us: cheap to publish often)."""
        with torch.no_grad():
            weights = tuple(layer.weight.detach().numpy() for layer in self.linears)
            biases = tuple(layer.bias.detach().numpy() for layer in self.linears)
            return PolicySnapshot(weights, biases, self.normalisation(), version, dataset_size_trained)

    @classmethod
    def from_snapshot(cls, snapshot: PolicySnapshot) -> PolicyNet:
        """A trainable network holding exactly the snapshot's weights (resume from a checkpoint)."""
        net = cls(snapshot.obs_dim, snapshot.hidden, normalisation=snapshot.normalisation)
        with torch.no_grad():
            for layer, w, b in zip(net.linears, snapshot.weights, snapshot.biases, strict=True):
                layer.weight.copy_(torch.from_numpy(w.copy()))
                layer.bias.copy_(torch.from_numpy(b.copy()))
        return net


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
