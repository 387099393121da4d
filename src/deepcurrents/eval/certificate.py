"""A sharper area bound: the trained current, concentrated onto its meshed level of phase.

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
(the uniform part keeps q > 0). Next to Γ every level of the phase meets, and |ω'| ∼ κ/r has no finite variance
under those samples: a rare sample very close to Γ decides the estimate, and the sample standard error reads
low exactly when the estimate does (docs/notes/meshing.md). So, as ``eval.metrics.mass_estimate`` does, a tube
about Γ is integrated apart, by samples with density ∝ 1/r about it (``geometry.polyline.sample_tube``), where
|ω'|·r stays bounded.
"""

from __future__ import annotations

import math

import torch

from deepcurrents.eval.device import device_of
from deepcurrents.eval.level_sets import level_set_view
from deepcurrents.eval.meshing.phase import phase_from_f
from deepcurrents.eval.metrics import boundary_segments, mass_to_area
from deepcurrents.geometry.phase_map import von_mises_slope
from deepcurrents.geometry.polyline import sample_tube, tube_density


@torch.no_grad()
def sharpened_mass_estimate(current, sampler, level: float, kappa: float = 16.0, num_samples: int = 1 << 17,
                            chunk_size: int = 1 << 15, tube_radius: float = 0.0, tube_fraction: float = 0.125,
                            seed: int = 0) -> tuple[float, float]:
    """The mass bound of ψ'(φ)·ω (module docstring) as an area: (estimate, standard error), both in the same
    units as ``mass_to_area``. ``sampler.sample(n)`` → {"x": (n, 3), "weight": (n,)}: samples of [-1, 1]³ with
    the weights vol(U)/(vol(U)·q) that make weighted means unbiased (``data.sampling.mesh_sampler``: mostly in
    the cells around the phase mesh); ``level``: the mesh's phase φ* (the off-surface phase θ + π);
    ``kappa``: the von Mises concentration (0: the plain bound). A sharpened ``NeuralCurrent`` is read through its
    network's own current (``eval.level_sets.level_set_view``), as the mesher reads it: the level is one of that
    phase.

    ``tube_radius`` > 0: the points within it of Γ's segments (``geometry.polyline.tube_density``) are integrated
    apart, by ``tube_fraction`` × ``num_samples`` more samples with density ∝ 1/r about Γ (drawn with ``seed`` + 1),
    while the sampler's samples there count 0: the same unbiased estimate, with a finite variance (module
    docstring). The standard error adds the two parts' variances (independent samples)."""
    if current.dim != 3:
        raise ValueError("The sharpened bound is defined for 3D currents (the phase needs the solid angle).")
    dev = device_of(current)
    tube = boundary_segments(current) if tube_radius > 0 else None
    if tube is not None and float((tube[1] - tube[0]).norm(dim=-1).sum()) == 0:
        tube = None
    # not ``seed`` itself: a sampler seeded alike draws the same uniform stream, and the two parts' errors, whose
    # variances are added as independent, would move together
    gen = torch.Generator(device="cpu").manual_seed(seed + 1)

    def sharpened_norm(x: torch.Tensor) -> torch.Tensor:  # ψ'(φ)|ω| (n,), float64
        x = x.float().to(dev)
        f, omega = current(x, create_graph=False)
        return von_mises_slope(phase_from_f(current, x, f), level, kappa) * omega.norm(dim=-1).double()

    values, tube_values, done = [], [], 0
    with level_set_view(current):  # the mesh's level is one of the network's phase (a sharpened current's too)
        while done < num_samples:
            batch = sampler.sample(min(chunk_size, num_samples - done))
            x = batch["x"]
            v = sharpened_norm(x).cpu() * batch["weight"].double()
            if tube is not None:
                v = v.masked_fill(tube_density(x.double(), *tube, tube_radius) > 0, 0.0)
                xt, q = sample_tube(*tube, tube_radius, max(2, int(len(x) * tube_fraction)), gen)
                t = sharpened_norm(xt).cpu() / q  # each an unbiased estimate of ∫_T∩U |ω'| dx
                tube_values.append(t.masked_fill((xt.abs() > 1.0).any(-1), 0.0) / 2.0**3)  # as E_U's share
            values.append(v)
            done += len(x)
    v = torch.cat(values)
    mean, var = float(v.mean()), float(v.var() / v.numel())
    if tube_values:
        t = torch.cat(tube_values)
        mean, var = mean + float(t.mean()), var + float(t.var() / t.numel())
    scale = mass_to_area(1.0, 3, current.alpha_scale)
    return mean * scale, math.sqrt(var) * scale
