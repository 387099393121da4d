"""Random Fourier features (Tancik et al. 2020), frozen."""

from __future__ import annotations

import math

import torch
from torch import nn
from torch.autograd.function import once_differentiable


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
        return torch.cat(self.sin_cos(x), dim=-1)

    def sin_cos(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(sin(2π Bx), cos(2π Bx)), each (N, num_frequencies)."""
        proj = (2.0 * math.pi) * (x @ self.frequencies.T)
        return torch.sin(proj), torch.cos(proj)

    def input_gradient(self, grad_features: torch.Tensor, sin: torch.Tensor, cos: torch.Tensor) -> torch.Tensor:
        """Chain rule through the features: ∇_x f from ∂f/∂features. (N, 2K), (N, K), (N, K) → (N, in_dim).

        Differentiable in ``grad_features`` (so the current loss can be backpropagated to the MLP), with a
        hand-written backward that reuses sin and cos: autograd's double backward through sin/cos would
        recompute them and materialise several more (N, 2K) products (see benchmarks/train_step.py).
        """
        return _FourierInputGradient.apply(grad_features, sin, cos, self.frequencies)


class _FourierInputGradient(torch.autograd.Function):
    """g ↦ 2π (g_sin ⊙ cos − g_cos ⊙ sin) B; linear in g, so its backward is v ↦ 2π [cos ⊙ vBᵀ, −sin ⊙ vBᵀ]."""

    @staticmethod
    def forward(ctx, grad_features, sin, cos, freqs):
        ctx.save_for_backward(sin, cos, freqs)
        k = sin.shape[-1]
        g_sin, g_cos = grad_features[..., :k], grad_features[..., k:]
        return (2.0 * math.pi) * ((g_sin * cos - g_cos * sin) @ freqs)

    @staticmethod
    @once_differentiable
    def backward(ctx, grad_out):
        sin, cos, freqs = ctx.saved_tensors
        vb = (2.0 * math.pi) * (grad_out @ freqs.T)
        return torch.cat([vb * cos, -(vb * sin)], dim=-1), None, None, None
