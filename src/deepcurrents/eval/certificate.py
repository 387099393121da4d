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
neighbouring cells; ``data.sampling.mesh_sampler``), weighted by 1/q: an unbiased estimate whatever the cells
(the uniform part keeps q > 0).
"""

from __future__ import annotations

import math

import torch

from deepcurrents.eval.device import device_of
from deepcurrents.eval.level_sets import level_set_view
from deepcurrents.eval.meshing.phase import phase_from_f
from deepcurrents.eval.metrics import mass_to_area
from deepcurrents.geometry.phase_map import von_mises_slope


@torch.no_grad()
def sharpened_mass_estimate(current, sampler, level: float, kappa: float = 16.0, num_samples: int = 1 << 17,
                            chunk_size: int = 1 << 15) -> tuple[float, float]:
    """The mass bound of ψ'(φ)·ω (module docstring) as an area: (estimate, standard error), both in the same
    units as ``mass_to_area``. ``sampler.sample(n)`` → {"x": (n, 3), "weight": (n,)}: samples of [-1, 1]³ with
    the weights vol(U)/(vol(U)·q) that make weighted means unbiased (``data.sampling.mesh_sampler``: mostly in
    the cells around the phase mesh); ``level``: the mesh's phase φ* (the off-surface phase θ + π);
    ``kappa``: the von Mises concentration (0: the plain bound). A sharpened ``NeuralCurrent`` is read through its
    network's own current (``eval.level_sets.level_set_view``), as the mesher reads it: the level is one of that
    phase."""
    if current.dim != 3:
        raise ValueError("The sharpened bound is defined for 3D currents (the phase needs the solid angle).")
    dev = device_of(current)
    values, done = [], 0
    with level_set_view(current):  # the mesh's level is one of the network's phase (a sharpened current's too)
        while done < num_samples:
            batch = sampler.sample(min(chunk_size, num_samples - done))
            x = batch["x"].float().to(dev)
            f, omega = current(x, create_graph=False)
            phase = phase_from_f(current, x, f)
            w = von_mises_slope(phase, level, kappa) * omega.norm(dim=-1).double()
            values.append(w.cpu() * batch["weight"].double())
            done += len(x)
    v = torch.cat(values)
    scale = mass_to_area(1.0, 3, current.alpha_scale)
    return float(v.mean()) * scale, float(v.std() / math.sqrt(v.numel())) * scale
