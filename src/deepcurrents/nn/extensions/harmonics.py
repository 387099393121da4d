"""Phase harmonics (``model.net.phase_harmonics`` K > 0, 3D; beyond the paper).

f = h_0(x) + a·Σ_k [h_k(x) cos ku + h'_k(x) sin ku]/k with u = Ω_Γ(x)/2 and (h_0, h_k, h'_k) the MLP's 2K + 1
outputs. The minimal current's f is −a·Ω with Ω's branch cut on the surface: a sawtooth in u, whose jump a
Fourier-feature MLP can only smear. The harmonics of u are smooth off Γ and wind around Γ at every scale, so the
truncated sawtooth Σ_k (−1)^k 2·sin(k(u − c))/k is in reach of constant outputs, and a jump across any surface
spanning Γ in reach of smooth ones. ``start`` > 0: f = h_0 alone until that fraction of the budget, then the
harmonics ramp in (opened at once they settle a knotted curve's jump on a level set of the solid angle, far from
minimal; docs/notes/recipes.md). The gate is the buffer ``harmonic_gate``."""

from __future__ import annotations

import torch

from deepcurrents.geometry.biot_savart import solid_angle
from deepcurrents.nn.extensions import CurrentExtension, opened


class PhaseHarmonics(CurrentExtension):
    """K harmonics of Γ's angle u in f's output basis, opening at the fraction ``start`` of the budget."""

    def __init__(self, harmonics: int, start: float = 0.0):
        self.harmonics, self.start = int(harmonics), float(start)
        self.outputs = 2 * self.harmonics

    def attach(self, current: torch.nn.Module) -> None:
        current.register_buffer("harmonic_gate", torch.tensor(0.0 if self.start > 0 else 1.0))

    def read_state(self, current: torch.nn.Module) -> None:
        self.gate = float(current.harmonic_gate)

    @property
    def needs_angle(self) -> bool:
        return self.gate > 0.0

    @property
    def follows_progress(self) -> bool:
        return self.start > 0

    def set_progress(self, current: torch.nn.Module, progress: float) -> None:
        if self.start > 0:
            self.gate = opened(progress, self.start)
            current.harmonic_gate.fill_(self.gate)

    def output_basis(self, current: torch.nn.Module, x: torch.Tensor, u: torch.Tensor | None) -> tuple:
        """e = [1, g·a·cos(ku)/k, g·a·sin(ku)/k]_{k=1..K} and ∂e/∂u = [0, −g·a·sin(ku), g·a·cos(ku)], a the
        current's alpha_scale, g the gate; u computed here unless given. (N, 3) → 2 × (N, 2K + 1), no gradient
        (e enters f as data; its x-derivative is added through α, ``NeuralCurrent._current``)."""
        with torch.no_grad():
            if self.gate == 0.0:  # not open yet: f = h_0, and no solid angle to compute
                basis = x.new_zeros(x.shape[0], 1 + self.outputs)
                basis[:, 0] = 1.0
                return basis, torch.zeros_like(basis)
            if u is None:
                u = 0.5 * solid_angle(x.detach(), current.loops)
            k = torch.arange(1, self.harmonics + 1, dtype=x.dtype, device=x.device)
            ku = u[:, None] * k
            cos, sin = torch.cos(ku), torch.sin(ku)
            a = current.alpha_scale * current.harmonic_gate.to(x.dtype)
            ones = torch.ones_like(u)[:, None]
            basis = torch.cat([ones, cos * (a / k), sin * (a / k)], dim=1)
            slope = torch.cat([torch.zeros_like(ones), sin * -a, cos * a], dim=1)
        return basis, slope
