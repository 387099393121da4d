"""The paper's meshing method (§5.2): the level set f = s, s the mean of f over Γ.

One level for the whole surface: it misses sheets where f's jump does not straddle s (an undertrained
trefoil), but it suits currents trained under a reconstruction metric, whose phase may turn twice. The
level set also holds a "complementary" spanning surface where ∇f cancels α; there the uncancelled rest of
α points against ∇f, while on the surface the current flows along ∇f (cos ≈ +1): faces are kept where
cos(ω, ∇f) ≥ ``min_alignment``.

One level assumes f is about constant along Γ. A trained f need not be: on a family's wrist f varied along Γ
by nearly its whole jump, so near part of Γ the level set f = s stayed clear of the curve and its cut border
(at the tube) did not run around Γ to be zipped. With ``level_blend`` = R > 0 (beyond the paper) the level
follows f along Γ near it: s(x) = s + w(d)·Σ_j k_j(x)(f(γ_j) − s), d the distance to Γ, w a smoothstep from 1
on Γ to 0 at R, k_j a softmax of −|x − γ_j|²/2(R/4)² over points γ_j of Γ (continuous everywhere, unlike the
nearest point, which jumps across a loop's middle). Beyond R it is the paper's level.
"""

from __future__ import annotations

import numpy as np
import torch

from deepcurrents.eval.device import device_of
from deepcurrents.eval.meshing.method import MeshMethod
from deepcurrents.geometry.polyline import closed_loop_segments, resample_polyline


def f_on_boundary(current, loops: list[np.ndarray], spacing: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Γ (loops (M_i, 3)) resampled every ``spacing`` and f there → (points (P, 3), f (P,)), float32."""
    starts, ends, _ = closed_loop_segments(loops)
    x = torch.as_tensor(resample_polyline(starts, ends, spacing), dtype=torch.float32, device=device_of(current))
    return x, current.evaluate(x, omega=False).reshape(-1)


def level_on_boundary(current, loops: list[np.ndarray], spacing: float) -> float:
    """s = mean of f over Γ (loops (M_i, 3)), by arc length: Γ resampled every ``spacing`` (paper §5.2)."""
    return float(f_on_boundary(current, loops, spacing)[1].mean())


class BoundaryLevelOffset:
    """s(x) − s of the blended level (module docstring): f's offset from the mean level along Γ, carried a
    distance R off Γ. gamma (P, 3) points of Γ, f_gamma (P,) f there, level s, radius R > 0."""

    def __init__(self, gamma: torch.Tensor, f_gamma: torch.Tensor, level: float, radius: float):
        self.gamma, self.offset, self.radius = gamma, (f_gamma - level).detach(), float(radius)
        self.box = torch.stack([gamma.min(0).values - radius, gamma.max(0).values + radius])

    def __call__(self, x: torch.Tensor, chunk_size: int = 1 << 14) -> torch.Tensor:
        """x (N, 3) → offset (N,), differentiable in x; 0 beyond R (only points in Γ's box grown by R are
        evaluated)."""
        out = torch.zeros(len(x), dtype=x.dtype, device=x.device)
        box, gamma, offset = self.box.to(x), self.gamma.to(x), self.offset.to(x)
        near = ((x >= box[0]) & (x <= box[1])).all(-1).nonzero().squeeze(-1)
        width2 = 2 * (self.radius / 4) ** 2
        parts = []
        for idx in torch.split(near, chunk_size):
            d2 = torch.cdist(x[idx], gamma).square()
            u = (d2.min(1).values.clamp_min(1e-24).sqrt() / self.radius).clamp(max=1.0)
            weight = 1 - u * u * (3 - 2 * u)
            parts.append(weight * (torch.softmax(-d2 / width2, dim=1) * offset).sum(1))
        if parts:
            out = out.index_put((near,), torch.cat(parts))
        return out


def aligned_with_grad_f(current, x: torch.Tensor, omega: torch.Tensor, min_alignment: float) -> torch.Tensor:
    """Where the current flows along ∇f = ω − alpha_scale·α: cos(ω, ∇f) ≥ ``min_alignment``.
    x (P, d), ω there (P, d) → (P,) bool."""
    grad_f = omega - current.alpha(x)
    cos = (omega * grad_f).sum(-1) / (omega.norm(dim=-1) * grad_f.norm(dim=-1)).clamp_min(1e-30)
    return cos >= min_alignment


class LevelSetMethod(MeshMethod):
    """f = s (or f − (s(x) − s) = s with ``level_blend`` > 0); Newton on g = f − s(x) with ∇g by autograd;
    faces kept where ω flows along ∇f."""

    name = "level_set"

    def __init__(self, current, chunk_size: int = 1 << 16, level_blend: float = 0.0):
        super().__init__(current, chunk_size)
        if not level_blend >= 0:
            raise ValueError(f"level_blend={level_blend} must be ≥ 0 (0: the paper's one level).")
        self.level_blend = float(level_blend)
        self.blend: BoundaryLevelOffset | None = None

    def sample(self, points, shape, loops, voxel):
        f = self.current.evaluate(points, self.chunk_size, omega=False).reshape(-1)
        gamma, f_gamma = f_on_boundary(self.current, loops, voxel / 4)
        self.level = float(f_gamma.mean())
        if self.level_blend > 0:
            self.blend = BoundaryLevelOffset(gamma, f_gamma, self.level, self.level_blend)
            f = f - self.blend(points)
        return f.cpu().numpy().reshape(tuple(shape)), self.level

    @property
    def reported_level(self) -> float:
        return self.level

    def empty_reason(self) -> str:
        return f"The level set f = {self.level:.4g} does not cross"

    def keep_carrying(self, centroids, omega, min_alignment):
        return aligned_with_grad_f(self.current, centroids, omega, min_alignment)

    def residual(self, x):
        with torch.enable_grad():
            c = x.detach().requires_grad_(True)
            f = self.current.f(c).reshape(-1)
            if self.blend is not None:
                f = f - self.blend(c)
            (g,) = torch.autograd.grad(f.sum(), c)
        return f.detach() - self.level, g
