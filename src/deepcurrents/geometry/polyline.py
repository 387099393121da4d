"""Closest points on polylines (Γ): brute force in torch (any device, with the segment and its parameter),
and exact distances through libigl's AABB tree on the CPU (for many points against many segments); the tube
of points near Γ, its sampling density and samples (the final mass estimate integrates it apart)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import igl
import numpy as np
import torch
from scipy.spatial import cKDTree


@dataclass
class PolylineProjection:
    """Closest points of N query points on a set of segments.

    distance (N,), point (N, 3), segment (N,) index of the closest segment, t (N,) ∈ [0, 1] position on it.
    """

    distance: torch.Tensor
    point: torch.Tensor
    segment: torch.Tensor
    t: torch.Tensor


def project_to_segments(
    points: torch.Tensor, starts: torch.Tensor, ends: torch.Tensor, chunk_size: int | None = None
) -> PolylineProjection:
    """Closest point on any segment [starts_i, ends_i] to each point. points (N, D); starts, ends (S, D)."""
    starts = starts.to(points)
    ends = ends.to(points)
    seg = ends - starts
    len2 = (seg * seg).sum(-1).clamp_min(1e-30)
    if chunk_size is None:
        chunk_size = max(256, (1 << 23) // max(1, starts.shape[0]))
    out_d, out_s, out_t = [], [], []
    for p in torch.split(points, chunk_size):
        rel = p.unsqueeze(1) - starts.unsqueeze(0)  # (n, S, D)
        t = ((rel * seg).sum(-1) / len2).clamp(0.0, 1.0)
        diff = rel - t.unsqueeze(-1) * seg
        d2 = (diff * diff).sum(-1)
        best = d2.argmin(dim=1)
        out_d.append(d2.gather(1, best[:, None]).squeeze(1).sqrt())
        out_s.append(best)
        out_t.append(t.gather(1, best[:, None]).squeeze(1))
    segment, t = torch.cat(out_s), torch.cat(out_t)
    point = starts[segment] + t.unsqueeze(-1) * seg[segment]
    return PolylineProjection(torch.cat(out_d), point, segment, t)


def segment_distance(points: np.ndarray, starts: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """Exact distance from each point to the nearest segment [starts_i, ends_i], through libigl's AABB tree:
    O((N + S) log S) where ``project_to_segments`` is O(N·S), so thousands of segments cost little.

    points (N, 3), starts, ends (S, 3) → (N,) float64."""
    return closest_on_segments(points, starts, ends)[0]


def closest_on_segments(points: np.ndarray, starts: np.ndarray, ends: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The nearest point on any segment [starts_i, ends_i] to each point, its distance and that segment's index
    (libigl's AABB tree, as ``segment_distance``).
    points (N, 3), starts, ends (S, 3) → (distances (N,), closest points (N, 3), segments (N,) int64)."""
    points = np.ascontiguousarray(points, dtype=np.float64)
    if len(points) == 0:
        return np.zeros(0), np.zeros((0, 3)), np.zeros(0, dtype=np.int64)
    s = len(starts)
    verts = np.ascontiguousarray(np.concatenate([starts, ends]), dtype=np.float64)
    edges = np.stack([np.arange(s), np.arange(s) + s], 1).astype(np.int64)
    d2, segment, closest = igl.point_mesh_squared_distance(points, verts, edges)
    return (np.sqrt(np.maximum(d2, 0.0)), np.asarray(closest, dtype=np.float64),
            np.asarray(segment, dtype=np.int64).reshape(-1))


def closed_loop_segments(loops: Sequence[np.ndarray | torch.Tensor]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Segments of closed loops as numpy arrays: (starts (S, D), ends (S, D), loop index (S,))."""
    loops = [np.asarray(lp, dtype=np.float64) for lp in loops]
    starts = np.concatenate(loops)
    ends = np.concatenate([np.roll(lp, -1, 0) for lp in loops])
    owner = np.concatenate([np.full(len(lp), i) for i, lp in enumerate(loops)])
    return starts, ends, owner


def resample_polyline(starts: np.ndarray, ends: np.ndarray, spacing: float) -> np.ndarray:
    """Points along segments at most ``spacing`` apart, endpoints included. → (P, D)."""
    lengths = np.linalg.norm(ends - starts, axis=1)
    counts = np.maximum(1, np.ceil(lengths / spacing).astype(int))
    idx = np.repeat(np.arange(len(starts)), counts)
    frac = np.concatenate([np.arange(c) / c for c in counts])
    return np.concatenate([starts[idx] + frac[:, None] * (ends - starts)[idx], ends])


def polyline_hausdorff(
    a_starts: np.ndarray, a_ends: np.ndarray, b_starts: np.ndarray, b_ends: np.ndarray, spacing: float = 1e-3
) -> float:
    """Symmetric Hausdorff distance between two sets of segments.

    Each side is resampled at ``spacing`` and its points are projected exactly onto the other's segments
    (``segment_distance``), so the result is within ``spacing``/2 of the exact value. a_*, b_* (S, 3).
    """
    def one_side(s0, s1, t0, t1):
        return float(segment_distance(resample_polyline(s0, s1, spacing), t0, t1).max())

    return max(one_side(a_starts, a_ends, b_starts, b_ends), one_side(b_starts, b_ends, a_starts, a_ends))


def resample_loop(loop: np.ndarray, n: int, corner_degrees: float = 30.0) -> np.ndarray:
    """A closed loop (M, D) resampled to ``n`` vertices spaced evenly by arc length, keeping its corners.

    Vertices where the loop turns by more than ``corner_degrees`` are kept exactly (the sharpest first, at
    most n // 2 of them); the other vertices are spread over the arcs between consecutive corners in
    proportion to their lengths, so the vertex order (the orientation) and the start are unchanged.
    A loop with at most ``n`` vertices is returned as it is. → (n, D).
    """
    loop = np.asarray(loop, dtype=np.float64)
    m = len(loop)
    if m <= n:
        return loop
    seg = np.roll(loop, -1, 0) - loop
    lengths = np.linalg.norm(seg, axis=1)
    arc = np.concatenate([[0.0], np.cumsum(lengths)])  # arc[i] = position of vertex i; arc[m] = total
    total = arc[-1]
    # turning angle at each vertex, between the incoming and the outgoing segment
    d_in, d_out = np.roll(seg, 1, 0), seg
    cos = (d_in * d_out).sum(1) / np.maximum(lengths * np.roll(lengths, 1), 1e-300)
    turn = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    corners = np.flatnonzero(turn > corner_degrees)
    if len(corners) > n // 2:
        corners = np.sort(corners[np.argsort(-turn[corners], kind="stable")[: n // 2]])
    anchors = np.union1d(corners, [0])  # the first vertex stays first
    starts = arc[anchors]
    ends = np.append(starts[1:], total)
    spans = ends - starts
    # every arc keeps its anchor; the remaining vertices go to the arcs by length (largest remainders)
    extra = n - len(anchors)
    share = spans / total * extra
    counts = np.floor(share).astype(int)
    counts[np.argsort(-(share - counts), kind="stable")[: extra - counts.sum()]] += 1
    positions = np.concatenate([s + span * np.arange(c + 1) / (c + 1) for s, span, c in zip(starts, spans, counts,
                                                                                              strict=True)])
    # points at those arc lengths along the closed polyline
    closed = np.concatenate([loop, loop[:1]])
    idx = np.clip(np.searchsorted(arc, positions, side="right") - 1, 0, m - 1)
    frac = (positions - arc[idx]) / np.maximum(lengths[idx], 1e-300)
    return closed[idx] + frac[:, None] * (closed[idx + 1] - closed[idx])


def _segment_normals(starts: torch.Tensor, ends: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Two unit normals e1, e2 of each segment (with its direction d, (d, e1, e2) is orthonormal). → 2 × (S, 3)"""
    d = ends - starts
    d = d / d.norm(dim=-1, keepdim=True).clamp_min(1e-30)
    axis = torch.zeros_like(d)
    axis[torch.arange(len(d)), d.abs().argmin(dim=-1)] = 1.0  # the axis least aligned with d
    e1 = torch.linalg.cross(d, axis)
    e1 = e1 / e1.norm(dim=-1, keepdim=True)
    return e1, torch.linalg.cross(d, e1)


def tube_density(points: torch.Tensor, starts: torch.Tensor, ends: torch.Tensor, radius: float) -> torch.Tensor:
    """The density q(x) of ``sample_tube``'s points: Σ over the segments j whose cylinder C_j (the points
    projecting onto the segment itself, 0 ≤ t_j ≤ 1, at distance r_j < ``radius`` from its line) holds x of
    1 / (2π L radius r_j(x)), L the total length of the segments; 0 outside the tube T = ∪_j C_j. Where
    cylinders overlap (the inside of a bend, two parts of Γ closer than 2·radius) their densities add; the
    wedges outside a bend, within ``radius`` of a vertex but in no cylinder, are not in T. Only the segments
    whose midpoint is within reach of a point are tested (a k-d tree's pairs), not all of them.

    points (N, 3); starts, ends (S, 3) → (N,) in points' dtype and device (computed in float64 on the CPU)."""
    p = points.detach().cpu().double().numpy()
    a = starts.detach().cpu().double().numpy()
    seg = ends.detach().cpu().double().numpy() - a
    length = np.linalg.norm(seg, axis=-1)
    q = np.zeros(len(p))
    if len(p) and length.max() > 0:
        reach = radius + 0.5 * float(length.max())  # every point of C_j is within this of its midpoint
        pairs = cKDTree(p).sparse_distance_matrix(cKDTree(a + 0.5 * seg), reach, output_type="ndarray")
        i, j = pairs["i"], pairs["j"]
        rel = p[i] - a[j]
        t = (rel * seg[j]).sum(-1) / np.maximum(length[j] ** 2, 1e-30)
        r2 = ((rel - t[:, None] * seg[j]) ** 2).sum(-1)
        inside = (t >= 0.0) & (t <= 1.0) & (r2 < radius * radius) & (length[j] > 0)
        np.add.at(q, i[inside], 1.0 / np.sqrt(np.maximum(r2[inside], 1e-300)))
        q /= 2.0 * math.pi * float(length.sum()) * radius
    return torch.from_numpy(q).to(device=points.device, dtype=points.dtype)


def sample_tube(starts: torch.Tensor, ends: torch.Tensor, radius: float, n: int,
                generator: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
    """n points of the tube T of ``tube_density`` around the segments: a segment with probability ∝ its length,
    a uniform position along it, a distance uniform in [0, radius) from it and a uniform angle about it. Their
    density ∝ 1/r near Γ is what makes E[g/q] over them finite-variance for integrands g ∼ 1/r (a current's
    |ω| next to Γ), where uniform samples' variance diverges.

    starts, ends (S, 3) → points (n, 3), their density q (n,) (``tube_density``), in starts' dtype on the CPU."""
    starts, ends = starts.detach().cpu(), ends.detach().cpu()
    length = (ends - starts).norm(dim=-1)
    j = torch.multinomial(length.double() / length.sum(), n, replacement=True, generator=generator)
    u = torch.rand(n, 3, generator=generator, dtype=starts.dtype)
    e1, e2 = _segment_normals(starts, ends)
    r = radius * u[:, 1:2]
    angle = 2.0 * math.pi * u[:, 2:3]
    x = starts[j] + u[:, :1] * (ends[j] - starts[j]) + r * (angle.cos() * e1[j] + angle.sin() * e2[j])
    return x, tube_density(x, starts, ends, radius)


def loop_gaps(loops: Sequence[np.ndarray]) -> np.ndarray:
    """For each closed loop (M_i, 3), the smallest distance from it to another loop (from any vertex of one to any
    segment of the other, both ways); ``inf`` for a single loop. → (L,)."""
    gaps = np.full(len(loops), np.inf)
    for i, a in enumerate(loops):
        for j, b in enumerate(loops):
            if j != i:
                b = np.asarray(b, np.float64)
                d = float(closest_on_segments(np.asarray(a, np.float64), b, np.roll(b, -1, 0))[0].min())
                gaps[i], gaps[j] = min(gaps[i], d), min(gaps[j], d)
    return gaps


def loop_gap(loops: Sequence[np.ndarray]) -> float:
    """The smallest distance between two different closed loops (each (M_i, 3)); ``inf`` for a single loop."""
    return float(loop_gaps(loops).min()) if len(loops) else np.inf
