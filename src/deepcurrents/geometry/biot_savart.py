"""Closed-form Biot–Savart fields α_Γ of boundaries (paper eq. biot-savart).

In 3D, Γ is one or more closed polygonal loops and α is the gradient of the solid angle Ω_Γ seen from x
(up to sign). In 2D, Γ is a set of signed points and α is the gradient of the total signed angle.
Both are unscaled: the model multiplies by ``alpha_scale``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

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


def _next_vertex(loops: Sequence[torch.Tensor], device: torch.device) -> torch.Tensor:
    """Index of each vertex's successor in the concatenated loops (the last of a loop → its first). → (S,)."""
    nxt, base = [], 0
    for loop in loops:
        m = loop.shape[0]
        nxt.append((torch.arange(m, device=device) + 1) % m + base)
        base += m
    return torch.cat(nxt)


def _cross_matrices(t: torch.Tensor) -> torch.Tensor:
    """B with (t_i × x)_k = (x @ B[k])_i for every segment i: the cross product as three (3, S) matrices, so that
    t × (v − x) for all point–segment pairs is a matrix product (``segment_table``'s line map). t (S, 3) → (3, 3, S)."""
    zero = torch.zeros_like(t[:, 0])
    tx, ty, tz = t.unbind(1)
    # rows: (t × x)_x = ty·z − tz·y, (t × x)_y = tz·x − tx·z, (t × x)_z = tx·y − ty·x
    return torch.stack([torch.stack([zero, -tz, ty]), torch.stack([tz, zero, -tx]), torch.stack([-ty, tx, zero])])


def _biot_savart_chunk(points: torch.Tensor, verts: torch.Tensor, nxt: torch.Tensor, length: torch.Tensor,
                       line_map: torch.Tensor, line_offset: torch.Tensor, plucker: torch.Tensor) -> torch.Tensor:
    """α at points (n, 3) from closed polylines given per segment i (start vertex i, end vertex nxt[i]).

    Everything is an (n, S) matrix, never (n, S, 3): with r0 = v_i − x and r1 = v_nxt − x, the three components
    of t × r0 = t × v − t × x and t·r0 = t·v − t·x are one matrix product (n, 3) @ (3, 4S), t·r1 = t·r0 + |seg|,
    1/|r| is computed once per vertex (each vertex ends one segment and starts the next), and Σ_i w_i (t_i × r0_i)
    = W (t × v) − (W t) × x, W t and W (t × v) one product with the lines' Plücker coordinates. Rounding is that of
    the direct form, whose r0 = v − x also carries the O(1) coordinates' rounding where r0 is small.
    """
    segments = verts.shape[0]
    r2 = None
    for k in range(3):  # |v − x|² per vertex, from the differences themselves (accurate next to Γ)
        d = verts[:, k].unsqueeze(0) - points[:, k : k + 1]
        r2 = d * d if r2 is None else r2.addcmul_(d, d)
    # (n, S): 1/|r0| of segment i is inv[:, i], 1/|r1| is inv[:, nxt[i]]. The floor keeps rsqrt's derivative (∝ inv³)
    # finite in float32; a point that close to a vertex gets nothing from either of its segments anyway (_LINE_EPS)
    inv = r2.clamp_min_(1e-24).rsqrt_()
    lines = torch.addmm(line_offset, points, line_map, alpha=-1.0)  # (n, 4S): [t × r0 (x, y, z) | t · r0]
    c0, c1, c2 = lines[:, :segments], lines[:, segments:2 * segments], lines[:, 2 * segments:3 * segments]
    cross_sq = (c0 * c0).addcmul_(c1, c1).addcmul_(c2, c2)  # |t × r0|², the squared distance to the line
    t_r0 = lines[:, 3 * segments:]
    # index_select: faster than inv[:, nxt] here
    coef = (t_r0 + length).mul_(inv.index_select(1, nxt)).addcmul_(t_r0, inv, value=-1.0)
    # on a segment's line: no contribution (coef / ∞ = 0, with a zero gradient, where a division by ~0 would not be)
    weight = coef / torch.where(cross_sq > _LINE_EPS, cross_sq, torch.inf)  # (n, S)
    sums = weight @ plucker  # (n, 6): [W (t × v) | W t]
    return sums[:, :3] - torch.linalg.cross(sums[:, 3:], points, dim=-1)


class SegmentTable(NamedTuple):
    """What ``biot_savart`` needs of the loops' segments (i from vertex i to vertex nxt[i], unit tangent t_i),
    computed once per Γ: vertices (S, 3), nxt (S,), lengths (S,); ``line_map`` (3, 4S) and ``line_offset`` (4S,)
    with offset − x @ map = [t × (v − x) per component | t · (v − x)] for a point x; ``plucker`` (S, 6), the lines'
    Plücker coordinates [t × v | t]."""

    verts: torch.Tensor
    nxt: torch.Tensor
    length: torch.Tensor
    line_map: torch.Tensor
    line_offset: torch.Tensor
    plucker: torch.Tensor


def segment_table(loops: Sequence[torch.Tensor] | torch.Tensor, dtype: torch.dtype | None = None,
                  device: torch.device | str | None = None) -> SegmentTable:
    """The segments of closed loops (list of (M_i, 3), or one (M, 3)) in ``dtype`` on ``device`` (default: the
    loops' own): a fixed Γ's table can be kept and handed to every ``biot_savart`` call (``NeuralCurrent`` does,
    saving some twenty small operations a training step: kernel launches on a GPU)."""
    if isinstance(loops, torch.Tensor):
        loops = [loops]
    loops = [loop.to(dtype=dtype or loop.dtype, device=device or loop.device) for loop in loops]
    verts = torch.cat(loops, dim=0)
    nxt = _next_vertex(loops, verts.device)
    seg = verts[nxt] - verts
    length = seg.norm(dim=-1)
    t = seg / length.unsqueeze(-1)
    moment = torch.linalg.cross(t, verts, dim=-1)  # t × v
    segments = verts.shape[0]
    line_map = torch.cat([_cross_matrices(t).permute(1, 0, 2).reshape(3, 3 * segments), t.T], dim=1)
    line_offset = torch.cat([moment.T.reshape(3 * segments), (t * verts).sum(-1)])
    return SegmentTable(verts, nxt, length, line_map, line_offset, torch.cat([moment, t], dim=1))


def biot_savart(
    points: torch.Tensor,
    loops: Sequence[torch.Tensor] | torch.Tensor | None = None,
    chunk_size: int | None = None,
    segments: SegmentTable | None = None,
) -> torch.Tensor:
    """Biot–Savart field α_Γ(x) = ∮_Γ dℓ × r / |r|³ of closed polygonal loops, in closed form.

    For segment i with unit tangent t_i and r0_i, r1_i the vectors from x to its initial and final vertex,
    α(x) = Σ_i (t_i·(r̂1_i − r̂0_i)) (t_i × r0_i) / |t_i × r0_i|²; a point on a segment's line gets nothing
    from that segment (zero off the segment, undefined on it).

    Args:
        points: (N, 3) query points.
        loops: list of (M_i, 3) closed loops (vertex order is the orientation; no repeated end vertex),
            or a single (M, 3) tensor.
        chunk_size: points per chunk; the work per chunk is about a dozen (chunk, S) matrices. Defaults so
            that one chunk holds about 2^22 point–segment pairs, which bounds memory for millions of points.
        segments: the loops' ``segment_table`` in the points' dtype and device, instead of ``loops`` (the same
            numbers, without recomputing it).

    Returns:
        (N, 3), same dtype and device as ``points``; differentiable in ``points`` and the loops.
        For the counter-clockwise unit circle in the xy-plane, α(0) = (0, 0, -2π).
    """
    if segments is None:  # per-segment quantities, once per call (not per chunk)
        if loops is None:
            raise ValueError("biot_savart needs the loops or their segment_table (segments=...).")
        segments = segment_table(loops, points.dtype, points.device)
    args = tuple(segments)
    if chunk_size is None:
        chunk_size = max(256, (1 << 22) // max(1, segments.verts.shape[0]))
    if points.shape[0] <= chunk_size:
        return _biot_savart_chunk(points, *args)
    return torch.cat([_biot_savart_chunk(p, *args) for p in torch.split(points, chunk_size)], dim=0)


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


def angle_2d(points: torch.Tensor, poles: torch.Tensor, signs: torch.Tensor) -> torch.Tensor:
    """Σ_j s_j·angle(x − p_j), the 2D analogue of the solid angle (one branch, modulo 2π; ∇ of it is
    ``biot_savart_2d``). points (N, 2), poles (P, 2), signs (P,) → (N,), the dtype of ``points``."""
    d = points.unsqueeze(1) - poles.to(dtype=points.dtype, device=points.device).unsqueeze(0)  # (N, P, 2)
    return (signs.to(dtype=points.dtype, device=points.device) * torch.atan2(d[..., 1], d[..., 0])).sum(-1)


def solid_angle(points: torch.Tensor, loops: Sequence[torch.Tensor] | torch.Tensor,
                chunk_size: int | None = None) -> torch.Tensor:
    """Solid angle Ω_Γ(x) of closed loops seen from points (one branch, modulo 4π), with α_Γ = ∇Ω_Γ.

    Sums the signed solid angles of the triangles (c, v_i, v_{i+1}) seen from x, c the loop's centroid
    (Van Oosterom–Strackee formula); the branch cut is that fan of triangles. For the counter-clockwise
    circle of radius R in the xy-plane, Ω(0, 0, z) = 2π(1 − z/√(z² + R²)) for z > 0.

    points: (N, 3) → (N,). ``chunk_size``: points per chunk (default: about 2^22 point–vertex pairs).
    """
    if isinstance(loops, torch.Tensor):
        loops = [loops]
    loops = [loop.to(dtype=points.dtype, device=points.device) for loop in loops]
    if chunk_size is None:
        chunk_size = max(256, (1 << 22) // max(1, sum(loop.shape[0] for loop in loops)))
    return torch.cat([_solid_angle_chunk(p, loops) for p in torch.split(points, chunk_size)])


def _solid_angle_chunk(points: torch.Tensor, loops: Sequence[torch.Tensor]) -> torch.Tensor:
    """Van Oosterom–Strackee with (n, M) matrices per coordinate (no (n, M, 3) tensors, no rolled copies of
    them): the loop with its first vertex repeated at the end gives v − x per vertex as (n, M + 1), and b
    (this vertex) and d (the next) are its column slices, views rather than gathered copies (faster, the
    same numbers). (n, 3) → (n,)."""
    total = torch.zeros(points.shape[0], dtype=points.dtype, device=points.device)
    for loop in loops:
        closed = torch.cat([loop, loop[:1]])  # (M + 1, 3)
        a = loop.mean(0).unsqueeze(0) - points  # (n, 3): x to the centroid
        v = [closed[:, k].unsqueeze(0) - points[:, k : k + 1] for k in range(3)]  # (n, M + 1) each
        b, d = [vk[:, :-1] for vk in v], [vk[:, 1:] for vk in v]
        an = a.norm(dim=-1, keepdim=True)  # (n, 1)
        vn = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt()
        bn, dn = vn[:, :-1], vn[:, 1:]
        av = a[:, :1] * v[0] + a[:, 1:2] * v[1] + a[:, 2:] * v[2]
        ab, ad = av[:, :-1], av[:, 1:]
        bd = b[0] * d[0] + b[1] * d[1] + b[2] * d[2]
        triple = (a[:, :1] * (b[1] * d[2] - b[2] * d[1]) + a[:, 1:2] * (b[2] * d[0] - b[0] * d[2])
                  + a[:, 2:] * (b[0] * d[1] - b[1] * d[0]))  # a · (b × d)
        denom = an * bn * dn + ab * dn + ad * bn + bd * an
        total = total - 2.0 * torch.atan2(triple, denom).sum(1)
    return total
