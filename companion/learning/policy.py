"""The trainable policy network (torch) and its immutable NumPy snapshot.

``PolicyNet`` is the network the learner starts from (its seeded initial weights come from
torch's generator). ``PolicySnapshot`` and ``Normalisation`` live in
:mod:`companion.learning.snapshot`, which needs no torch, and are re-exported here.

Shape and bounds: ``obs_dim -> hidden... -> 4`` with ReLU between hidden layers and ``tanh`` on
the last layer, so every action is strictly inside [-1, 1] without clipping (the paper's
joystick range). Inputs are normalised inside the model, ``(obs - mean) / std``, and the
normalisation travels with the weights (snapshot, checkpoint).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import cast

import torch
from torch import nn

from companion.learning.snapshot import Normalisation, PolicySnapshot
from companion.msg.command import ACT_DIM, ACTION_NAMES
from companion.msg.observation import OBS_DIM

__all__ = ["ACTION_NAMES", "ACT_DIM", "Normalisation", "PolicyNet", "PolicySnapshot"]


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
