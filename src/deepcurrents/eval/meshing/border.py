"""Closing a mesh's border onto Γ: cut the mesh exactly along the tube of radius τ around Γ (triangles are
clipped on the iso-line of the distance to Γ, not removed whole), then join each cut border loop to its
loop of Γ by a strip of triangles (a "zipper" ordered by arc-length parameter), so that the mesh's border
is Γ itself. Near Γ the network is smooth while α is singular, so what the field says there is not trusted.

Where several cut border loops run along one loop of Γ, the extracted set has more than one sheet leaving
Γ. On reconstructions this is a cap: the network also represents the part sealed across its opening (the
hand closed beyond the wrist, the head below the neck), and the level set holds that cap as a disk just
outside the opening, spanning Γ, whose faces (oriented along ω like the rest) make with the part one
consistently oriented closed surface. Its border therefore runs along Γ the other way round: the part's
own border runs against Γ's direction (ω flows against the Stokes normal of Γ's orientation, see
``data.targets``), the cap's along it. ``close_onto_loops`` zips the loop with that Stokes sense and drops
the pieces whose only Γ borders were passed over, so the mesh's border is Γ and nothing else. A cap can also
come loose: a small disk just beyond the opening, outside the tube, whose border does not run along Γ at all
(family members with a small surface-hinge margin). Such a floating piece is joined to no loop of Γ and spans no
part of it; once some piece is zipped, floating pieces smaller than ``MAX_FLOATING`` of the mesh are dropped
too (a larger one is more likely a torn part of the surface, and is kept for ``boundary_error`` to show).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import numpy as np
import torch

from deepcurrents.geometry.polyline import closed_loop_segments, project_to_segments, segment_distance
from deepcurrents.geometry.topology import border_loops, face_components

log = logging.getLogger(__name__)

# How a border of a mesh whose faces are oriented along ω runs along the loop of Γ it closes onto: −1,
# against Γ's direction, since ω flows against the right-hand (Stokes) normal of Γ's orientation (for the
# flat disk of ``data.targets``, f = −alpha_scale·Ω_Γ drops across the sheet along that normal).
STOKES_WINDING = -1.0
# Bordered pieces joined to no loop of Γ below this fraction of the mesh's area are dropped once some piece is
# zipped (module docstring): a loose cap is a small share of a mesh, and its border lies off Γ while it stays.
MAX_FLOATING = 0.1


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


def cut_tube(vertices: np.ndarray, faces: np.ndarray, loops: list[np.ndarray], tube: float | Sequence[float]
             ) -> tuple[np.ndarray, np.ndarray]:
    """The part of a mesh farther than ``tube`` from Γ (loops (M_i, 3)), clipped exactly on the tube's
    surface (``clip_by_field`` of min_i (distance to loop i − τ_i)); ``tube`` one radius or one per loop.
    → (vertices (V', 3), faces (F', 3))."""
    tubes = np.broadcast_to(np.asarray(tube, np.float64), (len(loops),))
    field = np.full(len(vertices), np.inf)
    for loop, t in zip(loops, tubes, strict=True):
        starts, ends, _ = closed_loop_segments([loop])
        field = np.minimum(field, segment_distance(vertices, starts, ends) - t)
    return clip_by_field(vertices, faces, field)


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


def _winding_if_along(points: np.ndarray, loop: np.ndarray, max_distance: float) -> float | None:
    """The signed winding of a closed polyline (P, 3) along a loop of Γ (n, 3) if it runs once along it
    within ``max_distance`` (median), else None."""
    par, dist = _loop_parameter(points, loop)
    winding = _winding_along(par)
    return winding if np.median(dist) < max_distance and abs(abs(winding) - 1.0) < 0.1 else None


def zip_to_loop(vertices: np.ndarray, border: np.ndarray, loop: np.ndarray, rows: int = 1
                ) -> tuple[np.ndarray, np.ndarray] | None:
    """Triangles joining a mesh border loop to a closed curve, ordered by the curve's arc-length parameter.

    vertices (V, 3); border: indices of the border loop in the mesh's orientation; loop (n, 3) the curve.
    ``rows`` > 1 splits the strip into that many rows: rows − 1 rings between border and curve, each with
    the curve's n parameters, at (1 − t)·border + t·curve (the same ruled strip, in triangles about
    τ/rows tall instead of τ-long slivers).
    Returns (new vertices (n·rows, 3) = the curve's then the rings', faces indexing [vertices; new]) or
    None when the border does not wind exactly once along the curve.
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
    # the ring next to the border: the curve itself, or the first of the rows − 1 rings (curve's order)
    first = base + order if rows <= 1 else base + n + np.arange(n)
    tris, i, k = [], 0, 0
    while i < m or k < n:
        bi, bj = walk[i % m], walk[(i + 1) % m]
        gk, gl = first[k % n], first[(k + 1) % n]
        if k >= n or (i < m and pb[i + 1] <= qg[k + 1]):
            tris.append((bi, gk, bj))
            i += 1
        else:
            tris.append((bi, gk, gl))
            k += 1
    tris = np.asarray(tris)
    new_vertices = loop
    if rows > 1:
        # the border at the curve's parameters (pb is where each border vertex sits; walk[m] = walk[0] at 1)
        at = vertices[np.append(walk, walk[0])]
        border_at = np.stack([np.interp(qg[:n], pb, at[:, c]) for c in range(3)], 1)
        t = np.arange(1, rows)[:, None, None] / rows
        rings = (1 - t) * border_at + t * loop[order]  # (rows − 1, n, 3)
        index = [base + n + j * n + np.arange(n) for j in range(rows - 1)] + [base + order]
        quads = []
        for lo, hi in zip(index[:-1], index[1:], strict=True):
            lo1, hi1 = np.roll(lo, -1), np.roll(hi, -1)
            quads += [np.stack([lo, hi, lo1], 1), np.stack([lo1, hi, hi1], 1)]
        tris = np.concatenate([tris, *quads])
        new_vertices = np.concatenate([loop, rings.reshape(-1, 3)])
    if not forward:
        tris = tris[:, ::-1]
    return new_vertices, tris


def triangle_areas(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Areas (F,) of triangles faces (F, 3) of vertices (V, 3)."""
    tri = vertices[faces]
    return 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)


def close_onto_loops(vertices: np.ndarray, faces: np.ndarray, loops: list[np.ndarray], spacing: float,
                     tube: float | Sequence[float], strip_rows: int | Sequence[int] = 1
                     ) -> tuple[np.ndarray, np.ndarray, int]:
    """Zips each loop of Γ (M_i, 3), densified to ``spacing``, to the border loop of the mesh that runs
    along it (winds once around Γ's parameter, as holes in the surface do not, within 5 ``tube`` radii; ``tube``
    and ``strip_rows`` one value or one per loop).

    One such border is zipped whatever its direction. Among several (a cap or a second sheet beside the
    surface, see the module docstring) the one running with ``STOKES_WINDING`` is zipped (of several of
    those, the one on the largest connected piece), and a connected piece of the mesh that has a passed-over
    border along Γ and none zipped is dropped, as is a bordered piece joined to no loop of Γ at all (below
    ``MAX_FLOATING`` of the area, once some piece is zipped). A Γ loop with no such border (the surface is torn near Γ),
    or whose borders all run the wrong way, is left open with a warning. The faces must be oriented along
    the current. ``strip_rows``: rows of each strip (``zip_to_loop``).

    vertices (V, 3), faces (F, 3) → (vertices (V', 3), faces (F', 3), number of loops closed).
    """
    borders = border_loops(faces)
    label = face_components(faces, len(vertices)) if len(faces) else np.zeros(0, dtype=int)
    piece_area = np.bincount(label, weights=triangle_areas(vertices, faces)) if len(faces) else np.zeros(0)
    vertex_piece = np.full(len(vertices), -1)
    vertex_piece[faces.reshape(-1)] = np.repeat(label, 3)
    tubes = np.broadcast_to(np.asarray(tube, np.float64), (len(loops),))
    rows = np.broadcast_to(np.asarray(strip_rows, np.int64), (len(loops),))
    chosen: list[tuple[np.ndarray, np.ndarray, int]] = []  # (border, densified Γ loop, strip rows)
    passed_over: list[np.ndarray] = []
    for loop, t, r in zip(loops, tubes, rows, strict=True):
        windings = [_winding_if_along(vertices[b], loop, 5 * t) for b in borders]
        along = [(b, w) for b, w in zip(borders, windings, strict=True) if w is not None]
        pick = None
        if len(along) == 1:
            pick = along[0][0]
        elif len(along) > 1:
            right = [b for b, w in along if np.sign(w) == STOKES_WINDING]
            if right:
                pick = max(right, key=lambda b: piece_area[vertex_piece[b[0]]])
            passed_over += [b for b, _ in along if b is not pick]
        if pick is None:
            why = "none" if not along else f"{len(along)}, none running against Γ as the current's border does"
            log.warning("Γ loop with %d vertices: %s of the cut border loops run along it; left open.",
                        len(loop), why)
            continue
        chosen.append((pick, _densify_loop(loop, spacing), int(r)))
    kept_pieces = {int(vertex_piece[b[0]]) for b, _, _ in chosen}
    drop: list[int] = []
    if passed_over:
        drop = sorted({int(vertex_piece[b[0]]) for b in passed_over} - kept_pieces)
        if drop:
            log.info("Dropped %d piece(s) of area %.4g (of %.4g) joined to Γ only by a passed-over border "
                     "(a cap or a second sheet).", len(drop), piece_area[drop].sum(), piece_area.sum())
    if chosen:
        bordered = {int(vertex_piece[b[0]]) for b in borders}
        floating = sorted(p for p in bordered - kept_pieces - set(drop)
                          if piece_area[p] < MAX_FLOATING * piece_area.sum())
        if floating:
            log.info("Dropped %d bordered piece(s) of area %.4g (of %.4g) joined to no loop of Γ (a loose cap).",
                     len(floating), piece_area[floating].sum(), piece_area.sum())
            drop = drop + floating
    if drop:
        faces = faces[~np.isin(label, drop)]
    new_v, new_f = [vertices], [faces]
    for border, dense, r in chosen:
        added_v, added_f = zip_to_loop(np.concatenate(new_v), border, dense, r)
        new_v.append(added_v)
        new_f.append(added_f)
    return np.concatenate(new_v), np.concatenate(new_f), len(chosen)
