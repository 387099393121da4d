"""Phase sharpening (``model.net.phase_sharpening`` κ > 0; beyond the paper, in no preset: docs/notes/recipes.md).

The current is the network's current concentrated onto one level of its own phase: ω = ψ'(φ)·(∇f_θ + a·α) and
f = f_θ + unit·(ψ(φ) − φ), with φ = (f_θ − b)/unit + u the network's phase (b the output bias, unit = 2a in 3D, a
in 2D) and ψ the von Mises map of the circle around a level c (``geometry.phase_map``). ω is again a current with
boundary Γ, and by the coarea formula its mass is the ψ'-weighted mean of the areas of the level sets {φ = t} near
c, where the plain current's mass is their plain mean: the far levels of a smeared jump stop counting. c is set
once, when the sharpening opens, to θ + π with θ the circular mean of φ over fixed points (the phase off the
surface). κ grows linearly from 0 after the fraction ``start`` of the budget. κ and c are the buffers
``sharpening`` and ``sharpening_level``. Train it with importance samples (``data.sampling.kind=importance``):
the loss moves level sets through f_θ's values, which few uniform samples see."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import torch

from deepcurrents.geometry.phase_map import von_mises_offset, von_mises_slope
from deepcurrents.nn.extensions import CurrentExtension, opened


class PhaseSharpening(CurrentExtension):
    """(f, ω) concentrated onto one level of the network's phase by the von Mises map of concentration κ."""

    def __init__(self, kappa: float, start: float = 0.0):
        self.full, self.start = float(kappa), float(start)

    def attach(self, current: torch.nn.Module) -> None:
        current.register_buffer("sharpening", torch.tensor(0.0 if self.start > 0 else self.full))
        current.register_buffer("sharpening_level", torch.tensor(float("nan")))

    def read_state(self, current: torch.nn.Module) -> None:
        self.kappa = float(current.sharpening)
        self.level_set = not torch.isnan(current.sharpening_level).item()

    @property
    def needs_angle(self) -> bool:
        return self.kappa > 0.0

    @property
    def follows_progress(self) -> bool:
        return self.start > 0

    def set_progress(self, current: torch.nn.Module, progress: float) -> None:
        if self.start > 0:
            self._set_kappa(current, self.full * opened(progress, self.start))

    def _set_kappa(self, current: torch.nn.Module, kappa: float) -> None:
        self.kappa = float(kappa)
        current.sharpening.fill_(self.kappa)

    @staticmethod
    def phase_unit(current: torch.nn.Module) -> float:
        """f per radian of phase: the jump of f across the surface is 2π times it (2a in 3D, a in 2D)."""
        return (2.0 if current.dim == 3 else 1.0) * current.alpha_scale

    def network_phase(self, current: torch.nn.Module, f: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        """φ = (f_θ − b)/unit + u, without the output bias b: b turns every level alike, and left in, Adam's steps of
        about lr on it would turn the phase by about a radian a step. f (N,), u (N,) → (N,), differentiable in f."""
        return (f - current.mlp.net[-1].bias[0]) / self.phase_unit(current) + u

    def transform(self, current: torch.nn.Module, f: torch.Tensor, omega: torch.Tensor | None,
                  u: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor | None]:
        """(f + unit·(ψ(φ) − φ), ψ'(φ)·ω); the identity while κ = 0 (not open yet, or read unsharpened)."""
        if u is None or self.kappa == 0.0:
            return f, omega
        phase = self.network_phase(current, f, u)
        if not self.level_set:
            self.open_level(current)
        level = current.sharpening_level.to(phase.dtype)
        f = f + self.phase_unit(current) * von_mises_offset(phase, level, self.kappa)
        return f, None if omega is None else von_mises_slope(phase, level, self.kappa)[:, None] * omega

    @torch.no_grad()
    def open_level(self, current: torch.nn.Module, probes: int = 4096) -> None:
        """Sets c = θ + π, θ the circular mean of the network's phase over fixed quasi-random points of [-1, 1]^d
        (the same on every DDP rank and at every resume, so c is too)."""
        weight = current.mlp.net[-1].weight
        x = torch.quasirandom.SobolEngine(current.dim, scramble=True, seed=0).draw(probes).to(weight) * 2.0 - 1.0
        u = current.boundary_angle(x)
        phase = self.network_phase(current, current.network_f(x, u), u)
        theta = torch.atan2(torch.sin(phase).mean(), torch.cos(phase).mean())
        current.sharpening_level.fill_(float(theta) + torch.pi)
        self.level_set = True

    @contextmanager
    def level_set_view(self, current: torch.nn.Module) -> Iterator[None]:
        """κ = 0 inside: ψ is monotone, so the sharpened current's level sets are those of the network's phase φ,
        which is smooth where ψ∘φ is steep (the meshers' coarse cells and Newton steps assume a smooth phase)."""
        kappa = self.kappa
        self._set_kappa(current, 0.0)
        try:
            yield
        finally:
            self._set_kappa(current, kappa)
