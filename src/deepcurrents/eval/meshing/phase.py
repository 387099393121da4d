"""The default meshing method: the surface where the current's phase turns over.

The phase φ = f/(2·alpha_scale) + Ω_Γ/2 of a 3D current is constant off its surface (mod 2π), since there
ω = ∇f + alpha_scale·∇Ω ≈ 0; across the surface f jumps by ±4π·alpha_scale, so e^{iφ} turns once around
the circle. Ω is defined modulo 4π, which e^{iφ} does not see: no branch cut. With θ the off-surface value
of φ (its circular mean over the grid's coarse nodes, most of them off the surface), the surface is the zero set
of sin(φ − θ) where cos(φ − θ) < 0: every sheet, whatever f's offset there (a single level of f misses
sheets where f's jump does not straddle it).
"""

from __future__ import annotations

import numpy as np
import torch
from scipy.ndimage import map_coordinates

from deepcurrents.eval.meshing.grid_angle import aliased_edges, grid_phase, phase_from_f
from deepcurrents.eval.meshing.method import MeshMethod


def current_phase(current, x: torch.Tensor, chunk_size: int = 1 << 16) -> torch.Tensor:
    """The phase φ = f/(2·alpha_scale) + Ω_Γ/2 of a 3D current at points x (P, 3) → (P,) float64 (see the
    module docstring): constant off the surface (mod 2π), turning once across it."""
    return torch.cat([phase_from_f(current, chunk, current.evaluate(chunk, chunk_size, omega=False))
                      for chunk in torch.split(x, chunk_size)])


class PhaseMethod(MeshMethod):
    """sin(φ − θ) = 0 where cos(φ − θ) < 0; Newton on g = sin(φ − θ), ∇g = cos(φ − θ)·ω/(2·alpha_scale)."""

    name = "phase"

    def sample(self, points, shape, loops, voxel):
        # exact near Γ and where the level θ + π can pass, interpolated elsewhere (meshing.grid_angle): the
        # network and the solid angle's closed form at every node were most of the meshing time
        info: dict = {}
        phase, self.theta = grid_phase(self.current, points, shape, loops, info=info)
        # where the phase turns by more than half a turn between two nodes, as points (extract_surface decides)
        edges = aliased_edges(phase.cpu().numpy().reshape(tuple(shape)), info["exact"][..., 0])
        flat = np.ravel_multi_index(edges.reshape(-1, 3).T, tuple(shape)) if len(edges) else np.zeros(0, int)
        self.aliased_points = points[torch.as_tensor(flat, device=points.device)].double().cpu().numpy() \
            .reshape(-1, 2, 3).mean(1)
        rel = (phase - self.theta).cpu().numpy().reshape(tuple(shape))
        self._side = np.cos(rel)
        return np.sin(rel), 0.0

    @property
    def reported_level(self) -> float:
        return self.theta

    def empty_reason(self) -> str:
        return "The current's phase does not turn over"

    def keep_marched(self, verts, faces):
        # sin(φ − θ) also vanishes off the surface (φ ≈ θ there): keep the faces where φ is opposite θ
        return faces[map_coordinates(self._side, verts.T, order=1)[faces].mean(1) < 0]

    def residual(self, x):
        f, omega = self.current.evaluate(x)
        rel = phase_from_f(self.current, x, f) - self.theta
        g = (torch.cos(rel).float() / (2.0 * self.current.alpha_scale)).unsqueeze(-1) * omega
        return torch.sin(rel).float(), g
