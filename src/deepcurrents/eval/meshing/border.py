"""Closing a mesh's border onto Γ: cut the mesh exactly along the tube of radius τ around Γ (triangles are
clipped on the iso-line of the distance to Γ, not removed whole), then join each cut border loop to its
loop of Γ by a strip of triangles (a "zipper" ordered by arc-length parameter), so that the mesh's border
is Γ itself. Near Γ the network is smooth while α is singular, so what the field says there is not trusted.
"""

from __future__ import annotations

import logging

import numpy as np
import torch

from deepcurrents.geometry.polyline import closed_loop_segments, project_to_segments
from deepcurrents.geometry.topology import border_loops

log = logging.getLogger(__name__)


def clip_by_field(vertices: np.ndarray, faces: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Keeps the part of a triangle mesh where a per-vertex field ≥ 0, clipping triangles on its zero
    iso-line (linear interpolation along edges; cut points shared between neighbours).

    vertices (V, 3), faces (F, 3), values (V,) → (vertices (V', 3), faces (F', 3)). Vectorised over faces.
    """
    inside = values >= 0
    fin = inside[faces]
    count = fin.sum(1)
    keep_faces = faces[count == 3]
    mixed = faces[(count == 1) | (count == 2)]
    if len(mixed) == 0:
        return vertices, keep_faces
    # rotate each mixed face so that its "odd" vertex comes first (the lone inside or lone outside one)
    mi = inside[mixed]
    lone_inside = mi.sum(1) == 1
    odd = np.where(lone_inside, np.argmax(mi, 1), np.argmin(mi, 1))
    rot = np.stack([odd, (odd + 1) % 3, (odd + 2) % 3], 1)
    tri = np.take_along_axis(mixed, rot, 1)  # orientation preserved by cyclic rotation
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    # cut points on edges (a,b) and (a,c); share them between faces through sorted edge keys
    edges = np.concatenate([np.stack([a, b], 1), np.stack([a, c], 1)])
    key = np.sort(edges, 1)
    uniq, inv = np.unique(key, axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    v0, v1 = values[uniq[:, 0]], values[uniq[:, 1]]
    w = v0 / (v0 - v1)
    cut_pts = vertices[uniq[:, 0]] + w[:, None] * (vertices[uniq[:, 1]] - vertices[uniq[:, 0]])
    # a cut at an edge's end is that vertex itself (no zero-length edges, no sliver triangles)
    fresh = len(vertices) + np.arange(len(w))
    cut_index = np.where(w <= 1e-12, uniq[:, 0], np.where(w >= 1 - 1e-12, uniq[:, 1], fresh))
    ab = cut_index[inv[: len(a)]]
    ac = cut_index[inv[len(a):]]
    new_faces = [keep_faces]
    li = lone_inside
    new_faces.append(np.stack([a[li], ab[li], ac[li]], 1))  # lone inside vertex: one triangle
    lo = ~li  # lone outside vertex a: quad (ab, b, c, ac) → two triangles
    new_faces.append(np.stack([ab[lo], b[lo], c[lo]], 1))
    new_faces.append(np.stack([ab[lo], c[lo], ac[lo]], 1))
    out = np.concatenate(new_faces)
    out = out[(out[:, 0] != out[:, 1]) & (out[:, 1] != out[:, 2]) & (out[:, 2] != out[:, 0])]
    return np.concatenate([vertices, cut_pts]), out


def cut_tube(vertices: np.ndarray, faces: np.ndarray, loops: list[np.ndarray], tube: float
             ) -> tuple[np.ndarray, np.ndarray]:
    """The part of a mesh farther than ``tube`` from Γ (loops (M_i, 3)), clipped exactly on the tube's
    surface (``clip_by_field`` of the distance to Γ minus τ). → (vertices (V', 3), faces (F', 3))."""
    starts, ends, _ = closed_loop_segments(loops)
    dist = project_to_segments(torch.as_tensor(vertices), torch.as_tensor(starts), torch.as_tensor(ends)).distance
    return clip_by_field(vertices, faces, dist.numpy() - tube)


def _densify_loop(loop: np.ndarray, spacing: float) -> np.ndarray:
    """Adds vertices on a closed loop's straight segments so that none is longer than ``spacing``."""
    ends = np.roll(loop, -1, 0)
    counts = np.maximum(1, np.ceil(np.linalg.norm(ends - loop, axis=1) / spacing).astype(int))
    idx = np.repeat(np.arange(len(loop)), counts)
    frac = np.concatenate([np.arange(c) / c for c in counts])
    return loop[idx] + frac[:, None] * (ends - loop)[idx]


def _loop_parameter(points: np.ndarray, loop: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Arc-length parameter in [0, 1) of the closest points on one closed loop, and the distances."""
    loop = np.ascontiguousarray(loop)
    ends = np.roll(loop, -1, 0)
    seglen = np.linalg.norm(ends - loop, axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seglen)[:-1]])
    proj = project_to_segments(torch.as_tensor(points), torch.as_tensor(loop), torch.as_tensor(ends))
    s = proj.segment.numpy()
    par = (cum[s] + proj.t.numpy() * seglen[s]) / seglen.sum()
    return par % 1.0, proj.distance.numpy()


def _winding_along(par: np.ndarray) -> float:
    """How many times a closed sequence of loop parameters in [0, 1) goes around (signed)."""
    steps = np.diff(np.concatenate([par, par[:1]]))
    return float(((steps + 0.5) % 1.0 - 0.5).sum())


def _follows_loop(points: np.ndarray, loop: np.ndarray, max_distance: float) -> bool:
    """Whether a closed polyline runs once along a loop of Γ, within ``max_distance`` (median)."""
    par, dist = _loop_parameter(points, loop)
    return bool(np.median(dist) < max_distance and abs(abs(_winding_along(par)) - 1.0) < 0.1)


def zip_to_loop(vertices: np.ndarray, border: np.ndarray, loop: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray] | None:
    """Triangles joining a mesh border loop to a closed curve, ordered by the curve's arc-length parameter.

    vertices (V, 3); border: indices of the border loop in the mesh's orientation; loop (n, 3) the curve.
    Returns (new vertices (n, 3) = the curve's, faces (m + n, 3) indexing [vertices; new]) or None when
    the border does not wind exactly once along the curve.
    """
    loop = np.ascontiguousarray(loop)
    par, _ = _loop_parameter(vertices[border], loop)
    winding = _winding_along(par)
    if abs(abs(winding) - 1.0) > 0.1:
        return None
    forward = winding > 0
    walk = border if forward else border[::-1]
    par_walk = par if forward else par[::-1]
    m, n = len(walk), len(loop)
    steps = np.diff(np.concatenate([par_walk, par_walk[:1]]))
    steps = (steps + 0.5) % 1.0 - 0.5
    pb = np.concatenate([[0.0], np.maximum.accumulate(np.cumsum(steps))])  # monotone, pb[m] ≈ 1
    pb = pb / pb[-1]
    ends = np.roll(loop, -1, 0)
    seglen = np.linalg.norm(ends - loop, axis=1)
    q = np.concatenate([[0.0], np.cumsum(seglen)[:-1]]) / seglen.sum()
    qg = (q - par_walk[0]) % 1.0
    order = np.argsort(qg, kind="stable")
    order = np.roll(np.arange(n), -int(order[0]))  # start at the curve vertex just past the border's start
    qg = np.concatenate([qg[order], [qg[order[0]] + 1.0]])
    base = len(vertices)
    tris, i, k = [], 0, 0
    while i < m or k < n:
        bi, bj = walk[i % m], walk[(i + 1) % m]
        gk, gl = base + order[k % n], base + order[(k + 1) % n]
        if k >= n or (i < m and pb[i + 1] <= qg[k + 1]):
            tris.append((bi, gk, bj))
            i += 1
        else:
            tris.append((bi, gk, gl))
            k += 1
    tris = np.asarray(tris)
    if not forward:
        tris = tris[:, ::-1]
    return loop, tris


def close_onto_loops(vertices: np.ndarray, faces: np.ndarray, loops: list[np.ndarray], spacing: float,
                     tube: float) -> tuple[np.ndarray, np.ndarray, int]:
    """Zips each loop of Γ (M_i, 3), densified to ``spacing``, to the one border loop of the mesh that runs
    along it (winds once around Γ's parameter, as holes in the surface do not, within 5 ``tube`` radii).
    A Γ loop with no such border (the surface is torn near Γ) or several is left open, with a warning.

    vertices (V, 3), faces (F, 3) → (vertices (V', 3), faces (F', 3), number of loops closed).
    """
    new_v, new_f = [vertices], [faces]
    borders = border_loops(faces)
    zipped = 0
    for loop in loops:
        dense = _densify_loop(loop, spacing)
        along = [b for b in borders if _follows_loop(vertices[b], loop, max_distance=5 * tube)]
        if len(along) != 1:
            log.warning("Γ loop with %d vertices: %d cut border loops run along it (need 1); left open.",
                        len(loop), len(along))
            continue
        added_v, added_f = zip_to_loop(np.concatenate(new_v), along[0], dense)
        new_v.append(added_v)
        new_f.append(added_f)
        zipped += 1
    return np.concatenate(new_v), np.concatenate(new_f), zipped
