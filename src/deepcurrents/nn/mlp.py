"""The field MLP h_θ that decodes features to the scalar f."""

from __future__ import annotations

import itertools

from torch import nn

ACTIVATIONS = {"softplus": nn.Softplus, "relu": nn.ReLU}


class FieldMLP(nn.Module):
    """``depth`` hidden layers of ``width`` units with softplus (paper) or ReLU (ablation), scalar output.

    (N, in_dim) → (N, out_dim), out_dim 1 by default.
    The paper's network: in_dim 2048, width 256, depth 4 → 722,177 weights.
    """

    def __init__(self, in_dim: int, width: int = 256, depth: int = 4, activation: str = "softplus",
                 out_dim: int = 1):
        super().__init__()
        self.out_dim = out_dim
        layers: list[nn.Module] = []
        dims = [in_dim] + [width] * depth
        for a, b in itertools.pairwise(dims):
            layers += [nn.Linear(a, b), ACTIVATIONS[activation]()]
        layers.append(nn.Linear(dims[-1], out_dim))  # out_dim 3: the closest-point baseline
        self.net = nn.Sequential(*layers)

    def forward(self, x):
        return self.net(x)
