"""Random Fourier features (Tancik et al. 2020), frozen."""

from __future__ import annotations

import math

import torch
from torch import nn


class FourierFeatures(nn.Module):
    """x ↦ [sin(2π Bx), cos(2π Bx)], B ~ N(0, σ²) of shape (num_frequencies, in_dim), frozen (a buffer).

    With ``enabled=False`` it is the identity (the paper's "no RFF" ablation).
    (N, in_dim) → (N, out_dim), out_dim = 2·num_frequencies (or in_dim when disabled).
    """

    def __init__(self, in_dim: int, num_frequencies: int = 1024, sigma: float = 2.0, enabled: bool = True,
                 seed: int | None = None):
        super().__init__()
        self.in_dim = in_dim
        self.enabled = enabled
        gen = torch.Generator().manual_seed(seed) if seed is not None else None
        freqs = torch.randn(num_frequencies if enabled else 0, in_dim, generator=gen) * sigma
        self.register_buffer("frequencies", freqs)

    @property
    def out_dim(self) -> int:
        return 2 * self.frequencies.shape[0] if self.enabled else self.in_dim

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if not self.enabled:
            return x
        proj = (2.0 * math.pi) * (x @ self.frequencies.T)
        return torch.cat([torch.sin(proj), torch.cos(proj)], dim=-1)
