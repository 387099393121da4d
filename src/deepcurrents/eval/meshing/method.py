"""What a meshing method is: how the surface of a 3D current shows on a grid (a volume and its iso-level),
which marched faces belong to it, and how a vertex is pulled back onto it. ``extract_surface`` does the
rest (grid, marching cubes, tube cut, |ω| test, orientation, border closing) the same way for every method.

A new method is a ``MeshMethod`` subclass in its own module, added to ``METHODS`` in ``surface.py``.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import ClassVar

import numpy as np
import torch

from deepcurrents.eval.device import device_of


class MeshMethod(ABC):
    """One meshing of one current, chosen once per ``extract_surface`` call.

    ``sample`` is called first, on the grid's nodes; the other methods may use what it found (the level).
    """

    name: ClassVar[str]

    def __init__(self, current, chunk_size: int = 1 << 16):
        self.current = current
        self.chunk_size = chunk_size

    @abstractmethod
    def sample(self, points: torch.Tensor, shape: tuple[int, int, int], loops: list[np.ndarray],
               voxel: float) -> tuple[np.ndarray, float]:
        """The field to march on the grid nodes ``points`` (G0·G1·G2, 3) (row-major in ``shape``) and the
        level of the surface in it → (volume (G0, G1, G2) float, level)."""

    @property
    @abstractmethod
    def reported_level(self) -> float:
        """The number a report calls the mesh's level (``MeshingResult.level``)."""

    @abstractmethod
    def empty_reason(self) -> str:
        """Why there is no surface when the volume does not cross its level (one clause for the log)."""

    def keep_marched(self, verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
        """Marching-cubes faces that belong to the surface. verts (V, 3) in voxel units, faces (F, 3) →
        the kept faces (F', 3). Default: all."""
        return faces

    def keep_carrying(self, centroids: torch.Tensor, omega: torch.Tensor, min_alignment: float) -> torch.Tensor:
        """Beyond |ω| ≥ δ, which faces carry the current: centroids (F, 3), ω there (F, 3) → (F,) bool.
        Default: all."""
        return torch.ones(len(centroids), dtype=torch.bool, device=centroids.device)

    @abstractmethod
    def residual(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """g and ∇g at points x (P, 3), g vanishing on the surface (Newton steps v ← v − g∇g/|∇g|²)
        → (g (P,), ∇g (P, 3)), float32."""

    def newton(self, verts: np.ndarray, max_step: float, steps: int) -> np.ndarray:
        """Moves vertices (V, 3) onto the surface by ``steps`` clamped Newton steps along ∇g, each at most
        ``max_step`` long (undoes marching cubes' linear-interpolation bias, which terraces surfaces
        steeper than the grid) → (V, 3) float64."""
        if steps <= 0 or len(verts) == 0:
            return verts
        dev = device_of(self.current)
        x = torch.as_tensor(verts, dtype=torch.float32, device=dev)
        for _ in range(steps):
            moved = []
            for chunk in torch.split(x, 1 << 15):
                value, g = self.residual(chunk)
                delta = (value / (g * g).sum(-1).clamp_min(1e-12)).unsqueeze(-1) * g
                norm = delta.norm(dim=-1, keepdim=True)
                delta = delta * torch.clamp(max_step / norm.clamp_min(1e-12), max=1.0)
                moved.append(chunk - delta)
            x = torch.cat(moved)
        return x.cpu().double().numpy()
