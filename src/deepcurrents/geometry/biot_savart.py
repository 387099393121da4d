"""Closed-form Biot–Savart fields α_Γ of boundaries (paper eq. biot-savart).

In 3D, Γ is one or more closed polygonal loops and α is the gradient of the solid angle Ω_Γ seen from x
(up to sign). In 2D, Γ is a set of signed points and α is the gradient of the total signed angle.
Both are unscaled: the model multiplies by ``alpha_scale``.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

# Points closer than this to the line through a segment get no contribution from that segment: on the
# line but off the segment the exact contribution is zero, on the segment α is undefined (measure zero).
_LINE_EPS = 1e-12
DEFAULT_CHUNK = 1 << 16


def loop_segments(loops: Sequence[torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
    """Segments of closed loops: each loop's last vertex connects to its first.

    loops: list of (M_i, 3) tensors. Returns (starts, ends), each (S, 3) with S = Σ M_i.
    """
    starts = torch.cat([loop for loop in loops], dim=0)
    ends = torch.cat([torch.roll(loop, shifts=-1, dims=0) for loop in loops], dim=0)
    return starts, ends


def _biot_savart_segments(points: torch.Tensor, starts: torch.Tensor, ends: torch.Tensor) -> torch.Tensor:
    """α at points (N, 3) from segments (S, 3)->(S, 3); broadcasts (N, S, 3) in memory."""
    seg = ends - starts
    t = seg / seg.norm(dim=-1, keepdim=True)  # (S, 3)
    r0 = starts.unsqueeze(0) - points.unsqueeze(1)  # (N, S, 3), from x to the initial vertex
    r1 = ends.unsqueeze(0) - points.unsqueeze(1)
    cross = torch.linalg.cross(t.expand_as(r0), r0, dim=-1)  # t × r0
    cross_sq = (cross * cross).sum(-1)  # |t × r0|², the squared distance to the segment's line
    safe = cross_sq > _LINE_EPS
    r0n = r0.norm(dim=-1).clamp_min(1e-30)
    r1n = r1.norm(dim=-1).clamp_min(1e-30)
    coef = (t * (r1 / r1n.unsqueeze(-1) - r0 / r0n.unsqueeze(-1))).sum(-1)
    # double-where keeps the gradient finite where the denominator vanishes
    denom = torch.where(safe, cross_sq, torch.ones_like(cross_sq))
    weight = torch.where(safe, coef / denom, torch.zeros_like(coef))
    return (weight.unsqueeze(-1) * cross).sum(1)


def biot_savart(
    points: torch.Tensor,
    loops: Sequence[torch.Tensor] | torch.Tensor,
    chunk_size: int | None = None,
) -> torch.Tensor:
    """Biot–Savart field α_Γ(x) = ∮_Γ dℓ × r / |r|³ of closed polygonal loops, in closed form.

    Args:
        points: (N, 3) query points.
        loops: list of (M_i, 3) closed loops (vertex order is the orientation; no repeated end vertex),
            or a single (M, 3) tensor.
        chunk_size: points per chunk; the work per chunk is (chunk, S, 3). Defaults so that one chunk
            holds about 2^24 point–segment pairs, which bounds memory for millions of points.

    Returns:
        (N, 3), same dtype and device as ``points``; differentiable in ``points`` and the loops.
        For the counter-clockwise unit circle in the xy-plane, α(0) = (0, 0, -2π).
    """
    if isinstance(loops, torch.Tensor):
        loops = [loops]
    loops = [loop.to(dtype=points.dtype, device=points.device) for loop in loops]
    starts, ends = loop_segments(loops)
    if chunk_size is None:
        chunk_size = max(1024, (1 << 24) // max(1, starts.shape[0]))
    if points.shape[0] <= chunk_size:
        return _biot_savart_segments(points, starts, ends)
    return torch.cat(
        [_biot_savart_segments(p, starts, ends) for p in torch.split(points, chunk_size)], dim=0
    )


def biot_savart_2d(points: torch.Tensor, poles: torch.Tensor, signs: torch.Tensor) -> torch.Tensor:
    """2D Biot–Savart field of signed points: α(x) = Σ_j s_j J(x − p_j) / |x − p_j|².

    J is the rotation by +90°, so α is the gradient of Σ_j s_j · angle(x − p_j) (the 2D analogue of the
    solid angle; it jumps by 2π across a curve from the −1 point to the +1 point).

    Args:
        points: (N, 2); poles: (P, 2); signs: (P,) of ±1 (+1 where the curve ends, −1 where it starts).
    Returns:
        (N, 2), finite everywhere (zero contribution from a pole hit exactly).
    """
    poles = poles.to(dtype=points.dtype, device=points.device)
    signs = signs.to(dtype=points.dtype, device=points.device)
    d = points.unsqueeze(1) - poles.unsqueeze(0)  # (N, P, 2)
    r2 = (d * d).sum(-1)
    safe = r2 > _LINE_EPS
    inv = torch.where(safe, signs / torch.where(safe, r2, torch.ones_like(r2)), torch.zeros_like(r2))
    jd = torch.stack([-d[..., 1], d[..., 0]], dim=-1)
    return (inv.unsqueeze(-1) * jd).sum(1)


def solid_angle(points: torch.Tensor, loops: Sequence[torch.Tensor] | torch.Tensor) -> torch.Tensor:
    """Solid angle Ω_Γ(x) of closed loops seen from points (one branch, modulo 4π), with α_Γ = ∇Ω_Γ.

    Sums the signed solid angles of the triangles (c, v_i, v_{i+1}) seen from x, c the loop's centroid
    (Van Oosterom–Strackee formula); the branch cut is that fan of triangles. For the counter-clockwise
    circle of radius R in the xy-plane, Ω(0, 0, z) = 2π(1 − z/√(z² + R²)) for z > 0.

    points: (N, 3) → (N,).
    """
    if isinstance(loops, torch.Tensor):
        loops = [loops]
    total = torch.zeros(points.shape[0], dtype=points.dtype, device=points.device)
    for loop in loops:
        loop = loop.to(dtype=points.dtype, device=points.device)
        c = loop.mean(0)
        a = (c - points).unsqueeze(1)  # (N, 1, 3)
        b = loop.unsqueeze(0) - points.unsqueeze(1)  # (N, M, 3)
        d = torch.roll(b, shifts=-1, dims=1)
        an, bn, dn = a.norm(dim=-1), b.norm(dim=-1), d.norm(dim=-1)
        triple = (a * torch.linalg.cross(b, d, dim=-1)).sum(-1)  # (N, M)
        denom = an * bn * dn + (a * b).sum(-1) * dn + (a * d).sum(-1) * bn + (b * d).sum(-1) * an
        total = total - 2.0 * torch.atan2(triple, denom).sum(1)
    return total
