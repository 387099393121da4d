"""Losses: the current (mass) loss under a metric B, and the surface hinge loss."""

from __future__ import annotations

from collections.abc import Callable

import torch


def apply_metric(omega: torch.Tensor, metric: torch.Tensor | None) -> torch.Tensor:
    """B_x ω(x). omega: (N, d); metric: None (B = I), (N,) scalar weights, or (N, d, d) matrices."""
    if metric is None:
        return omega
    if metric.dim() == 1:
        return metric.unsqueeze(-1) * omega
    return torch.einsum("nij,nj->ni", metric, omega)


def current_loss(omega: torch.Tensor, metric: torch.Tensor | None = None,
                 weight: torch.Tensor | None = None) -> torch.Tensor:
    """L_curr = E_x |B_x ω(x)| (paper eq. massmin-deep-metric). omega: (N, d) → scalar.

    ``weight`` (N,): importance weights 1 / (vol(U)·density) of non-uniform samples (data.sampling), so the
    mean stays an unbiased estimate of the uniform expectation."""
    norms = apply_metric(omega, metric).norm(dim=-1)
    return (norms * weight).mean() if weight is not None else norms.mean()


def surface_loss(f_minus: torch.Tensor, f_plus: torch.Tensor, margin: float = 0.01) -> torch.Tensor:
    """L_surf = E[(δ − f(y − εn) + f(y + εn))^+]: f must drop by at least δ across the target along n.

    f_minus = f(y − ε n_y), f_plus = f(y + ε n_y), each (M,) → scalar. The sign is the paper's; it agrees
    with the orientation of Γ taken from the mesh's boundary loops (see data/ for how Γ is oriented).
    """
    return torch.relu(margin - f_minus + f_plus).mean()


def winding_loss(f_minus: torch.Tensor, f_plus: torch.Tensor, jump: float) -> torch.Tensor:
    """E[(f(y − εn) − f(y + εn) − J)^+]: f may drop by at most one full jump J = 4π·alpha_scale across the target
    (beyond the paper). More is a second turn of the phase, which the reconstruction metric w(I − n nᵀ) does not
    see (its gradient is along n) but the mass does: the dome by which a smooth network meets the surface hinge.
    f_minus, f_plus (M,) → scalar."""
    return torch.relu(f_minus - f_plus - jump).mean()


def surface_values(f: Callable[[torch.Tensor], torch.Tensor],
                   batch: dict[str, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
    """f on both sides of a batch's surface samples, evaluated once: y = batch["surface_points"],
    n = batch["surface_normals"], ε = batch["epsilon"], [y − εn | y + εn] stacked along the sample axis.

    y: (M, 3) with f: (2M, 3) → (2M,) (one current), or (S, M, 3) with f: (S, 2M, 3) → (S, 2M) (a family,
    one code per shape). → (f(y − εn), f(y + εn)), each flattened."""
    offset = batch["epsilon"].unsqueeze(-1) * batch["surface_normals"]
    y = batch["surface_points"]
    f_minus, f_plus = f(torch.cat([y - offset, y + offset], dim=-2)).chunk(2, dim=-1)
    return f_minus.flatten(), f_plus.flatten()


def level_loss(f: Callable[[torch.Tensor], torch.Tensor], batch: dict[str, torch.Tensor], boundary: torch.Tensor,
               margin: float, reach: float = 0.25, boundary_mask: torch.Tensor | None = None) -> torch.Tensor:
    """The level hinge (beyond the paper): E_y[(m − (f(y − ε'n) − s))^+ + (m + (f(y + ε'n) − s))^+], ε' = reach·ε,
    s the mean of f over points of Γ (the level the mesher takes, ``meshing.level_set``). The surface hinge only asks f
    to drop by δ across [y − εn, y + εn], which leaves where in that window the level f = s lies free; this one asks
    the drop to straddle s within ±ε' of the target. Like the surface hinge it costs 2m where f has no jump at all (a
    penalty on |f(y) − s| instead rewarded that: the surface vanished). batch: "surface_points" y (M, 3),
    "surface_normals" n (M, 3), "epsilon" (M,); boundary (P, 3) → scalar. A family: y, n (S, M, 3), ε (S, M), each
    shape's Γ points (S, P, 3) with ``boundary_mask`` (S, P) (padding False), f (S, N, 3) → (S, N): s per shape."""
    offset = (reach * batch["epsilon"]).unsqueeze(-1) * batch["surface_normals"]
    y = batch["surface_points"]
    count = y.shape[-2]
    values = f(torch.cat([y - offset, y + offset, boundary], dim=-2)).reshape(*y.shape[:-2], -1)
    inner, outer, gamma = values[..., :count], values[..., count:2 * count], values[..., 2 * count:]
    if boundary_mask is None:
        level = gamma.mean(-1, keepdim=True)
    else:
        weight = boundary_mask.to(gamma.dtype)
        level = (gamma * weight).sum(-1, keepdim=True) / weight.sum(-1, keepdim=True)
    return (torch.relu(margin - (inner - level)) + torch.relu(margin + (outer - level))).mean()


def surface_hinge(f: Callable[[torch.Tensor], torch.Tensor], batch: dict[str, torch.Tensor],
                  margin: float = 0.01) -> torch.Tensor:
    """``surface_loss`` of a batch's surface samples (``surface_values``). → scalar."""
    return surface_loss(*surface_values(f, batch), margin)
