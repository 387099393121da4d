"""Random Fourier features (Tancik et al. 2020), frozen."""

from __future__ import annotations

import math

import torch
from torch import nn
from torch.autograd.function import once_differentiable


class FourierFeatures(nn.Module):
    """x ↦ [w ⊙ sin(2π Bx), w ⊙ cos(2π Bx)], B ~ N(0, σ²) of shape (num_frequencies, in_dim), frozen (a buffer).

    w = 1 (the paper) unless ``coarse_to_fine`` > 0 (beyond the paper): then the frequencies open in order of
    |B_k| as training proceeds (``set_progress``): the ``coarse_start`` fraction with the smallest |B_k| from the
    first step, the rest ramping in by the fraction ``coarse_to_fine`` of the budget, after which w = 1 and the
    features are the plain ones. A smooth f is cheap to reach with few frequencies and the high ones are only
    needed to sharpen the jump late (the coarse-to-fine encodings of BARF, Lin et al. 2021, and SAPE, Hertz et
    al. 2021). The weights are a buffer, so a checkpoint taken mid-run evaluates as it trained.

    With ``enabled=False`` it is the identity (the paper's "no RFF" ablation).
    (N, in_dim) → (N, out_dim), out_dim = 2·num_frequencies (or in_dim when disabled).
    """

    RAMP = 0.1  # a frequency's weight ramps from 0 to 1 while the front passes this fraction of the ranks

    def __init__(self, in_dim: int, num_frequencies: int = 1024, sigma: float = 2.0, enabled: bool = True,
                 seed: int | None = None, coarse_to_fine: float = 0.0, coarse_start: float = 0.25):
        super().__init__()
        self.in_dim = in_dim
        self.enabled = enabled
        gen = torch.Generator().manual_seed(seed) if seed is not None else None
        freqs = torch.randn(num_frequencies if enabled else 0, in_dim, generator=gen) * sigma
        self.register_buffer("frequencies", freqs)
        self.coarse_to_fine, self.coarse_start = float(coarse_to_fine), float(coarse_start)
        if self.coarse_to_fine > 0 and enabled:
            # rank of each frequency by |B_k| in [0, 1): the order in which they open
            order = torch.argsort(freqs.norm(dim=1))
            ranks = torch.empty(len(order))
            ranks[order] = torch.arange(len(order), dtype=ranks.dtype) / max(len(order), 1)
            self.register_buffer("ranks", ranks, persistent=False)
            self.register_buffer("weights", torch.ones(len(order)))
            self.set_progress(0.0)
        else:
            self.weights = None

    @property
    def follows_progress(self) -> bool:
        """Whether training must call ``set_progress`` (coarse-to-fine frequencies)."""
        return self.weights is not None

    def set_progress(self, progress: float) -> None:
        """w at the fraction ``progress`` ∈ [0, 1] of the training budget (no-op without coarse_to_fine)."""
        if self.weights is None:
            return
        t = min(max(progress / self.coarse_to_fine, 0.0), 1.0)
        front = self.coarse_start + (1.0 + self.RAMP - self.coarse_start) * t
        ramp = ((front - self.ranks) / self.RAMP).clamp_(0.0, 1.0)
        self.weights.copy_(0.5 - 0.5 * torch.cos(math.pi * ramp))

    def feature_weights(self) -> torch.Tensor | None:
        """w repeated for [sin, cos], (2K,), or None when every weight is 1 by construction."""
        return None if self.weights is None else torch.cat([self.weights, self.weights])

    @property
    def out_dim(self) -> int:
        return 2 * self.frequencies.shape[0] if self.enabled else self.in_dim

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if not self.enabled:
            return x
        return torch.cat(self.sin_cos(x), dim=-1)

    def sin_cos(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(sin(2π Bx), cos(2π Bx)), each (N, num_frequencies)."""
        proj = x @ scaled_frequencies(self.frequencies)
        if self.weights is None:
            return torch.sin(proj), torch.cos(proj)
        return torch.sin(proj) * self.weights, torch.cos(proj) * self.weights

    def input_gradient(self, grad_features: torch.Tensor, sin: torch.Tensor, cos: torch.Tensor) -> torch.Tensor:
        """Chain rule through the features: ∇_x f from ∂f/∂features. (N, 2K), (N, K), (N, K) → (N, in_dim).

        ``sin`` and ``cos`` as ``sin_cos`` returns them (weighted: the Jacobian of the weighted features).
        Differentiable in ``grad_features`` (so the current loss can be backpropagated to the MLP), with a
        hand-written backward that reuses sin and cos: autograd's double backward through sin/cos would
        recompute them and materialise several more (N, 2K) products (see benchmarks/train_step.py).
        """
        return _FourierInputGradient.apply(grad_features, sin, cos, self.frequencies)


def scaled_frequencies(frequencies: torch.Tensor) -> torch.Tensor:
    """2π Bᵀ, contiguous: the features' phases are x @ 2π Bᵀ (the factor on this small matrix instead of a pass
    over the (N, K) phases; nn.field_gradient's pass computes their transpose, (2π Bᵀ)ᵀ xᵀ, the same in float32
    on MKL and within rounding elsewhere). (K, d) → (d, K)."""
    return ((2.0 * math.pi) * frequencies.T).contiguous()


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
