"""A sharper certified area bound: the trained current, concentrated onto its meshed level of phase.

The phase φ = f/(2s) + Ω_Γ/2 (s = alpha_scale, ``eval.meshing.phase``) has ∇φ = ω/(2s) and turns once (by 2π)
across the surface, so ω = 2s∇φ is the gradient of a circle-valued map, and by the coarea formula its mass is
the mean area of its level sets {φ ≡ c}, each a surface spanning Γ: mass(ω) = (1/2π) ∫ A(c) dc. A slowly
converging current has a smeared jump: its level sets are bulged caps, so their mean area stays above the
minimum long after one of them (the meshed one) is nearly minimal.

For any degree-one monotone map ψ of the circle (ψ(φ + 2π) = ψ(φ) + 2π), ω' = 2s∇(ψ∘φ) = ψ'(φ)·ω is again
a current with boundary Γ (f' = 2s(ψ(φ) − φ) + f is single valued), so its mass is again an upper bound of
the minimal area, now a weighted mean of level-set areas, (1/2π) ∫ ψ'(c) A(c) dc. With ψ' the von Mises
density around the meshed level φ* (concentration κ), that mean is over the level sets next to the mesh.
κ = 0 gives back the plain mass bound.

|ω'| lives in a thin shell around the mesh, so uniform samples would estimate it badly; samples are drawn
from a mixture of the uniform density and cells around the mesh (∝ mesh area per cell, spread to the
neighbouring cells), weighted by 1/q: an unbiased estimate whatever the cells (the uniform part keeps q > 0).
"""

from __future__ import annotations

import math

import numpy as np
import torch
import trimesh
from scipy.ndimage import uniform_filter
from scipy.special import i0e

from deepcurrents.eval.device import device_of
from deepcurrents.eval.meshing.phase import phase_from_f
from deepcurrents.eval.metrics import mass_to_area


def von_mises_weight(phase: torch.Tensor, level: float, kappa: float) -> torch.Tensor:
    """ψ'(φ) = exp(κ(cos(φ − level) − 1)) / i0e(κ), mean 1 over a turn of φ. (P,) → (P,) float64."""
    if kappa == 0.0:
        return torch.ones_like(phase, dtype=torch.float64)
    return torch.exp(kappa * (torch.cos(phase.double() - level) - 1.0)) / float(i0e(kappa))


def mesh_cells(mesh: trimesh.Trimesh, resolution: int, spread: int = 1) -> np.ndarray:
    """Probabilities (resolution³,) of the cells of [-1, 1]³ ∝ the mesh area whose face centres fall in them,
    averaged over each cell's (2·spread + 1)³ neighbourhood (the shell around a sheet reaches the next cells)."""
    h = 2.0 / resolution
    idx = np.clip(((np.asarray(mesh.triangles_center) + 1.0) / h).astype(np.int64), 0, resolution - 1)
    grid = np.zeros((resolution,) * 3)
    np.add.at(grid, (idx[:, 0], idx[:, 1], idx[:, 2]), np.asarray(mesh.area_faces))
    if spread > 0:
        grid = np.maximum(uniform_filter(grid, size=2 * spread + 1, mode="constant"), 0.0)  # no rounding below 0
    total = grid.sum()
    return (grid / total).ravel() if total > 0 else np.full(grid.size, 1.0 / grid.size)


@torch.no_grad()
def sharpened_mass_estimate(current, mesh: trimesh.Trimesh, level: float, kappa: float = 4.0,
                            num_samples: int = 1 << 18, seed: int = 0, resolution: int = 64,
                            uniform_fraction: float = 0.1, chunk_size: int = 1 << 15) -> tuple[float, float]:
    """The mass bound of ψ'(φ)·ω (module docstring) as an area: (estimate, standard error), both in the same
    units as ``mass_to_area``. ``mesh``: the current's phase mesh (in [-1, 1]³ coordinates); ``level``: its
    phase φ* (the off-surface phase θ + π); ``kappa``: the von Mises concentration (0: the plain bound).
    Deterministic mixture sampling: ``uniform_fraction`` of the samples uniform, the rest from the cells."""
    if current.dim != 3:
        raise ValueError("The sharpened bound is defined for 3D currents (the phase needs the solid angle).")
    dev = device_of(current)
    gen = torch.Generator(device="cpu").manual_seed(seed)
    probs = torch.as_tensor(mesh_cells(mesh, resolution), dtype=torch.float64)
    h = 2.0 / resolution
    n_uniform = max(int(round(num_samples * uniform_fraction)), 1)
    n_cells = num_samples - n_uniform
    lam = n_cells / num_samples  # the mixture's weight on the cells
    values = []
    for count, from_cells in ((n_uniform, False), (n_cells, True)):
        done = 0
        while done < count:
            n = min(chunk_size, count - done)
            if from_cells:
                cell = torch.multinomial(probs, n, replacement=True, generator=gen)
                ijk = torch.stack([cell // resolution**2, (cell // resolution) % resolution, cell % resolution], -1)
                x = (ijk.double() + torch.rand(n, 3, generator=gen, dtype=torch.float64)) * h - 1.0
            else:
                x = torch.rand(n, 3, generator=gen, dtype=torch.float64) * 2.0 - 1.0
                ijk = ((x + 1.0) / h).long().clamp(0, resolution - 1)
                cell = (ijk[:, 0] * resolution + ijk[:, 1]) * resolution + ijk[:, 2]
            # the mixture's density relative to the uniform one: (1 − λ) + λ·p_cell·(number of cells)
            q = (1.0 - lam) + lam * probs[cell] * resolution**3
            xf = x.float().to(dev)
            f, omega = current(xf, create_graph=False)
            phase = phase_from_f(current, xf, f)
            w = von_mises_weight(phase, level, kappa) * omega.norm(dim=-1).double()
            values.append(w.cpu() / q)
            done += n
    v = torch.cat(values)
    mean, stderr = float(v.mean()), float(v.std() / math.sqrt(v.numel()))
    scale = mass_to_area(1.0, 3, current.alpha_scale)
    return mean * scale, stderr * scale
