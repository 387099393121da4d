"""The von Mises map of the circle: a degree-one monotone ψ that concentrates a current's phase onto one level.

A current ω = 2s∇φ with circle-valued phase φ (s = alpha_scale, φ = f/(2s) + Ω_Γ/2) has the mass of the mean of
its level sets' areas (coarea). ψ'(φ)·ω = 2s∇(ψ∘φ) is again a current with boundary Γ for any ψ with
ψ(φ + 2π) = ψ(φ) + 2π, ψ' > 0, and its mass is the ψ'-weighted mean of the same areas. With ψ' the von Mises
density around a level c (concentration κ; mean 1 over a turn), that mean is over the level sets next to c:

    ψ'(φ) = exp(κ cos(φ − c)) / I_0(κ) = 1 + 2 Σ_{n≥1} (I_n(κ)/I_0(κ)) cos(n(φ − c))   (Jacobi–Anger)
    ψ(φ)  = φ + 2 Σ_{n≥1} (I_n(κ)/I_0(κ)) sin(n(φ − c)) / n

κ = 0 is the identity. Used by the certificate (``eval.certificate``) on a trained current and by
``NeuralCurrent``'s phase sharpening inside the model.
"""

from __future__ import annotations

import functools

import numpy as np
import torch
from scipy.special import i0e, ive

# Fourier terms of ψ − φ are kept while I_n(κ)/I_0(κ) ≥ this (≈ exp(−n²/2κ) for large κ: n ≤ 6.7√κ + 1)
_TERM_TOLERANCE = 1e-10


def von_mises_slope(phase: torch.Tensor, level: float | torch.Tensor, kappa: float) -> torch.Tensor:
    """ψ'(φ) = exp(κ(cos(φ − c) − 1)) / i0e(κ), mean 1 over a turn of φ; differentiable in φ.
    (P,) → (P,), the dtype of ``phase``."""
    if kappa == 0.0:
        return torch.ones_like(phase)
    return torch.exp(kappa * (torch.cos(phase - level) - 1.0)) / float(i0e(kappa))


def von_mises_offset(phase: torch.Tensor, level: float | torch.Tensor, kappa: float) -> torch.Tensor:
    """ψ(φ) − φ = 2 Σ_n (I_n(κ)/I_0(κ)) sin(n(φ − c))/n, a 2π-periodic function of φ; differentiable in φ.
    (P,) → (P,), the dtype of ``phase``."""
    if kappa == 0.0:
        return torch.zeros_like(phase)
    orders, coefficients = _offset_terms(float(kappa), phase.dtype, phase.device)
    return (torch.sin((phase - level)[:, None] * orders) * coefficients).sum(-1)


@functools.lru_cache(maxsize=16)
def _offset_terms(kappa: float, dtype: torch.dtype, device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
    """The orders n and coefficients 2 I_n(κ)/(n I_0(κ)) of ψ − φ, (T,) each, kept per (κ, dtype, device): a
    training step at a fixed κ then copies nothing to the device (on a GPU a blocking copy in every step was a
    synchronisation), and a new κ (the ramp) copies without blocking. Read-only. Made outside inference mode, so
    that a first call from an evaluation under ``torch.inference_mode`` does not hand later training steps inference
    tensors that autograd refuses to save."""
    n = np.arange(1, 1 + max(2, int(7.0 * np.sqrt(kappa)) + 2))
    ratios = ive(n, kappa) / ive(0, kappa)
    n, ratios = n[ratios >= _TERM_TOLERANCE], ratios[ratios >= _TERM_TOLERANCE]
    with torch.inference_mode(False):
        coefficients = torch.as_tensor(2.0 * ratios / n, dtype=dtype).to(device, non_blocking=True)
        return torch.as_tensor(n, dtype=dtype).to(device, non_blocking=True), coefficients
