"""The paper's meshing method (§5.2): the level set f = s, s the mean of f over Γ.

One level for the whole surface: it misses sheets where f's jump does not straddle s (an undertrained
trefoil), but it suits currents trained under a reconstruction metric, whose phase may turn twice. The
level set also holds a "complementary" spanning surface where ∇f cancels α; there the uncancelled rest of
α points against ∇f, while on the surface the current flows along ∇f (cos ≈ +1): faces are kept where
cos(ω, ∇f) ≥ ``min_alignment``.
"""

from __future__ import annotations

import numpy as np
import torch

from deepcurrents.eval.device import device_of
from deepcurrents.eval.meshing.method import MeshMethod
from deepcurrents.geometry.polyline import closed_loop_segments, resample_polyline


def level_on_boundary(current, loops: list[np.ndarray], spacing: float) -> float:
    """s = mean of f over Γ (loops (M_i, 3)), by arc length: Γ resampled every ``spacing`` (paper §5.2)."""
    starts, ends, _ = closed_loop_segments(loops)
    pts = resample_polyline(starts, ends, spacing)
    x = torch.as_tensor(pts, dtype=torch.float32, device=device_of(current))
    return float(current.evaluate(x, omega=False).mean())


def aligned_with_grad_f(current, x: torch.Tensor, omega: torch.Tensor, min_alignment: float) -> torch.Tensor:
    """Where the current flows along ∇f = ω − alpha_scale·α: cos(ω, ∇f) ≥ ``min_alignment``.
    x (P, d), ω there (P, d) → (P,) bool."""
    grad_f = omega - current.alpha(x)
    cos = (omega * grad_f).sum(-1) / (omega.norm(dim=-1) * grad_f.norm(dim=-1)).clamp_min(1e-30)
    return cos >= min_alignment


class LevelSetMethod(MeshMethod):
    """f = s; Newton on g = f − s with ∇g = ∇f by autograd; faces kept where ω flows along ∇f."""

    name = "level_set"

    def sample(self, points, shape, loops, voxel):
        f = self.current.evaluate(points, self.chunk_size, omega=False)
        self.level = level_on_boundary(self.current, loops, voxel / 4)
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
            f = self.current.f(c)
            (g,) = torch.autograd.grad(f.sum(), c)
        return f.detach() - self.level, g
