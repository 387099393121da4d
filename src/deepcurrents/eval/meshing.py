"""Meshing a neural current: the level set f = s (s = mean of f over Γ), cut to where the current lives,
with its border carried exactly onto Γ.

Paper §5.2 keeps the marching-cubes vertices where |ω| ≥ δ. Near Γ that test is meaningless (α is
singular and the network is smooth there), which leaves a ragged border and spurious faces. We instead

1. mesh the level set f = s on a grid over the region of interest (by default Γ's bounding box: a
   minimal surface lies in the convex hull of its boundary);
2. cut the mesh exactly along the tube of radius τ around Γ (triangles are clipped on the iso-line of
   the distance to Γ, not removed whole);
3. outside the tube, keep faces whose |ω| at the centroid is ≥ δ and where ω flows along ∇f (the level
   set also holds a complementary spanning surface where ∇f cancels α, and what α keeps there points
   against ∇f), and drop specks (small components);
4. move vertices onto the level set by a few clamped Newton steps along ∇f (undoes marching cubes'
   linear-interpolation bias, which terraces surfaces steeper than the grid);
5. close the tube: join each cut border loop to its boundary loop of Γ by a strip of triangles
   (a "zipper" ordered by arc-length parameter), so the mesh's border is Γ itself.

Where step 5 cannot match a border loop to its Γ loop (the surface is torn near Γ), that loop is left
open and ``boundary_error`` shows it.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
import torch
import trimesh
from scipy.ndimage import map_coordinates
from skimage.measure import find_contours, marching_cubes

from deepcurrents.geometry.biot_savart import solid_angle
from deepcurrents.geometry.polyline import closed_loop_segments, project_to_segments

log = logging.getLogger(__name__)


@dataclass
class MeshingResult:
    """The extracted mesh and what happened on the way (for metrics and logs)."""

    mesh: trimesh.Trimesh
    level: float  # the level s of f (method "level_set") or the off-surface phase θ (method "phase")
    bounds: np.ndarray
    voxel: float
    tube: float
    zipped_loops: int
    info: dict = field(default_factory=dict)


def _device(current) -> torch.device:
    return next(current.parameters()).device


def region_of_interest(loops: list[np.ndarray], padding: float = 0.15, domain: float = 1.0) -> np.ndarray:
    """Γ's bounding box grown by ``padding`` × its largest extent, clipped to the domain. → (2, 3)."""
    pts = np.concatenate(loops)
    lo, hi = pts.min(0), pts.max(0)
    pad = padding * float((hi - lo).max()) + 1e-3
    return np.stack([np.maximum(lo - pad, -domain), np.minimum(hi + pad, domain)])


def level_on_boundary(current, loops: list[np.ndarray], spacing: float) -> float:
    """s = mean of f over Γ, by arc length (paper §5.2)."""
    from deepcurrents.geometry.polyline import resample_polyline

    starts, ends, _ = closed_loop_segments(loops)
    pts = resample_polyline(starts, ends, spacing)
    x = torch.as_tensor(pts, dtype=torch.float32, device=_device(current))
    return float(current.evaluate(x, omega=False).mean())


def clip_by_field(vertices: np.ndarray, faces: np.ndarray, values: np.ndarray):
    """Keeps the part of a triangle mesh where a per-vertex field ≥ 0, clipping triangles on its zero
    iso-line (linear interpolation along edges; cut points shared between neighbours).

    Returns (vertices (V', 3), faces (F', 3)). Vectorised over faces.
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


def border_edges(faces: np.ndarray) -> np.ndarray:
    """The directed edges that belong to one face only, (E, 2), each following its face's orientation."""
    directed = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    key = np.sort(directed, 1)
    _, inv, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    return directed[counts[inv.reshape(-1)] == 1]


def border_loops(faces: np.ndarray) -> list[np.ndarray]:
    """Border loops of a triangle mesh as vertex index arrays, each following its faces' orientation.

    Walks edges, not vertices: where two loops touch at a vertex (two border edges leave it), each edge is
    still used once, and the walk splits there into simple loops. Border edges that close no loop
    (inconsistently oriented faces) are left out.
    """
    edges = border_edges(faces)
    outgoing: dict[int, list[int]] = {}
    for e, a in enumerate(edges[:, 0].tolist()):
        outgoing.setdefault(a, []).append(e)
    heads = edges[:, 1].tolist()
    used = np.zeros(len(edges), dtype=bool)
    loops = []
    for first in range(len(edges)):
        if used[first]:
            continue
        start, loop, e = int(edges[first, 0]), [], first
        while True:
            used[e] = True
            loop.append(int(edges[e, 0]))
            v = heads[e]
            if v == start:
                break
            e = next((k for k in outgoing.get(v, ()) if not used[k]), None)
            if e is None:
                break
        if v == start and len(loop) >= 3:
            loops.append(np.asarray(loop))
    return loops


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


def zip_to_loop(vertices: np.ndarray, border: np.ndarray, loop: np.ndarray):
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


def current_phase(current, x: torch.Tensor, chunk_size: int = 1 << 16) -> torch.Tensor:
    """The phase φ = f/(2·alpha_scale) + Ω_Γ/2 of a 3D current at points x (P, 3) → (P,) float64.

    Off the surface ω = ∇f + alpha_scale·∇Ω ≈ 0, so φ is constant there (mod 2π); across the surface f
    jumps by ±4π·alpha_scale, so e^{iφ} turns once around the circle. Ω is defined modulo 4π, which e^{iφ}
    does not see: no branch cut. The surface is where e^{iφ} is opposite its off-surface value."""
    return torch.cat([_phase(current, chunk, current.evaluate(chunk, chunk_size, omega=False))
                      for chunk in torch.split(x, chunk_size)])


def _phase(current, x: torch.Tensor, f: torch.Tensor) -> torch.Tensor:
    """φ at points x (P, 3) from f already evaluated there (P,) → (P,) float64."""
    omega = solid_angle(x.double(), [lp.to(x.device) for lp in current.loops])
    return f.double() / (2.0 * current.alpha_scale) + 0.5 * omega


def _newton_to_level(current, verts: np.ndarray, level: float, max_step: float, steps: int,
                     theta: float | None = None) -> np.ndarray:
    """Moves vertices onto the extracted level set by clamped Newton steps: v ← v − clamp(g∇g/|∇g|², max_step),
    with g = f − level (level set), or g = sin(φ − θ) and ∇g = cos(φ − θ)·ω/(2·alpha_scale) (phase)."""
    if steps <= 0 or len(verts) == 0:
        return verts
    dev = _device(current)
    x = torch.as_tensor(verts, dtype=torch.float32, device=dev)
    for _ in range(steps):
        moved = []
        for chunk in torch.split(x, 1 << 15):
            if theta is None:
                with torch.enable_grad():
                    c = chunk.detach().requires_grad_(True)
                    f = current.f(c)
                    (g,) = torch.autograd.grad(f.sum(), c)
                value = f.detach() - level
            else:
                f, omega = current.evaluate(chunk)
                rel = _phase(current, chunk, f) - theta
                value = torch.sin(rel).float()
                g = (torch.cos(rel).float() / (2.0 * current.alpha_scale)).unsqueeze(-1) * omega
            delta = (value / (g * g).sum(-1).clamp_min(1e-12)).unsqueeze(-1) * g
            norm = delta.norm(dim=-1, keepdim=True)
            delta = delta * torch.clamp(max_step / norm.clamp_min(1e-12), max=1.0)
            moved.append(chunk - delta)
        x = torch.cat(moved)
    return x.cpu().double().numpy()


def _drop_small_components(verts, faces, min_fraction: float):
    """Drops connected components with less than ``min_fraction`` of the total area (specks)."""
    if len(faces) == 0 or min_fraction <= 0:
        return faces
    mesh = trimesh.Trimesh(verts, faces, process=False)
    labels = trimesh.graph.connected_component_labels(mesh.face_adjacency, node_count=len(faces))
    areas = np.bincount(labels, weights=mesh.area_faces)
    return faces[(areas >= min_fraction * areas.sum())[labels]]


MESH_METHODS = ("phase", "level_set")
MESH_METHOD_CHOICES = ("auto", *MESH_METHODS)  # what evaluation.mesh.method and the apps accept


def mesh_method(options: dict, default: str) -> dict:
    """``options`` with ``method`` "auto" (or unset) replaced by the model kind's ``default``: "phase" for
    minimal currents (ω ≈ 0 off the surface, so the phase is constant there), "level_set" for currents
    trained under a reconstruction metric (ω along the target's normal is free off the surface, which
    can turn the phase over twice: doubled sheets)."""
    options = dict(options)
    if options.get("method") in (None, "auto"):
        options["method"] = default
    return options


@torch.no_grad()
def extract_surface(
    current,
    resolution: int = 128,
    delta: float = 5e-3,
    boundary_tube: float = 0.04,
    bounds: np.ndarray | None = None,
    padding: float = 0.15,
    newton_steps: int = 3,
    min_component: float = 0.01,
    min_alignment: float = 0.5,
    close_boundary: bool = True,
    method: str = "phase",
    chunk_size: int = 1 << 16,
) -> MeshingResult:
    """The surface of a 3D current as a triangle mesh whose border lies on Γ (see the module docstring).

    Args:
        current: a NeuralCurrent-like module with ``f``, ``evaluate``, ``loops``.
        resolution: grid cells along the longest side of ``bounds``.
        delta: keep faces with |ω| ≥ delta at their centroid (paper: 5e-3).
        boundary_tube: radius τ of the tube around Γ that is cut and closed by the strip (at least 1.5 voxels).
        bounds: (2, 3) region to mesh; default Γ's bounding box grown by ``padding``.
        min_component: drop components smaller than this fraction of the total area.
        min_alignment: keep faces where cos(ω, ∇f) is at least this (drops the complementary level
            surface, where ω points against ∇f).
        close_boundary: False gives the paper's mesh (|ω| ≥ δ cut only, no tube, no strip).
        method: "phase" (default): the zero set of sin(φ − θ) where cos(φ − θ) < 0, φ the current's phase
            (``current_phase``), θ its circular mean over the grid (the off-surface value): every sheet of
            the surface, whatever f's offset there. "level_set": the paper's f = s, one level for the whole
            surface (it misses sheets where f's jump does not straddle s, e.g. an undertrained trefoil).
    """
    if method not in MESH_METHODS:
        raise ValueError(f"method={method!r} must be one of {MESH_METHODS} (resolve 'auto' with mesh_method).")
    loops = [lp.detach().cpu().double().numpy() for lp in current.loops]
    if bounds is None:
        bounds = region_of_interest(loops, padding)
    bounds = np.asarray(bounds, dtype=np.float64)
    extent = bounds[1] - bounds[0]
    voxel = float(extent.max()) / resolution
    shape = np.maximum(2, np.ceil(extent / voxel).astype(int) + 1)
    axes = [np.linspace(bounds[0, i], bounds[0, i] + voxel * (shape[i] - 1), shape[i]) for i in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    dev = _device(current)
    points = torch.as_tensor(grid, dtype=torch.float32, device=dev)
    theta = None
    if method == "phase":
        phase = current_phase(current, points, chunk_size)
        theta = float(torch.angle(torch.exp(1j * phase).mean()))  # off the surface, where most of the grid is
        rel = (phase - theta).cpu().numpy().reshape(tuple(shape))
        vol, side = np.sin(rel), np.cos(rel)
        level = 0.0
    else:
        f = current.evaluate(points, chunk_size, omega=False)
        vol = f.cpu().numpy().reshape(tuple(shape))
        level = level_on_boundary(current, loops, voxel / 4)
    tube = max(boundary_tube, 1.5 * voxel) if close_boundary else 0.0
    empty = MeshingResult(trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), int)), level if theta is None else theta,
                          bounds, voxel, tube, 0)
    if not (vol.min() < level < vol.max()):
        what = ("The current's phase does not turn over" if theta is not None
                else f"The level set f = {level:.4g} does not cross")
        log.warning("%s in the meshing region; the mesh is empty.", what)
        return empty
    verts, faces, _, _ = marching_cubes(vol, level=level, spacing=(voxel,) * 3)
    if theta is not None:
        # sin(φ − θ) also vanishes off the surface (φ ≈ θ there): keep the faces where φ is opposite θ
        faces = faces[map_coordinates(side, (verts / voxel).T, order=1)[faces].mean(1) < 0]
    verts = verts.astype(np.float64) + bounds[0]
    faces = faces.astype(np.int64)

    starts, ends, _ = closed_loop_segments(loops)
    if tube > 0:
        dist = project_to_segments(torch.as_tensor(verts), torch.as_tensor(starts), torch.as_tensor(ends)).distance
        verts, faces = clip_by_field(verts, faces, dist.numpy() - tube)

    if len(faces):
        # The level set f = s also holds a "complementary" spanning surface where ∇f cancels α; there the
        # uncancelled rest of α points against ∇f, while on Σ the current flows along ∇f (cos ≈ +1).
        centroids = torch.as_tensor(verts[faces].mean(1), dtype=torch.float32, device=dev)
        _, omega = current.evaluate(centroids, chunk_size)
        keep = omega.norm(dim=-1) >= delta
        if tube > 0 and min_alignment > -1 and theta is None:
            grad_f = omega - current.alpha(centroids)
            cos = (omega * grad_f).sum(-1) / (omega.norm(dim=-1) * grad_f.norm(dim=-1)).clamp_min(1e-30)
            keep &= cos >= min_alignment
        faces = _drop_small_components(verts, faces[keep.cpu().numpy()], min_component)
    if len(faces) == 0:
        log.warning("No part of the level set carries the current (|ω| ≥ %.3g along ∇f); the mesh is empty.", delta)
        return empty
    used = np.unique(faces)
    remap = np.full(len(verts), -1)
    remap[used] = np.arange(len(used))
    verts, faces = verts[used], remap[faces]

    if tube > 0 and newton_steps > 0:
        verts = _newton_to_level(current, verts, level, voxel, newton_steps, theta)

    # orient the faces along the current: ω points along the normal of the surface it represents
    mesh = trimesh.Trimesh(verts, faces, process=False)
    centres = torch.as_tensor(np.array(mesh.triangles_center), dtype=torch.float32, device=dev)
    _, omega = current.evaluate(centres, chunk_size)
    flux = (mesh.face_normals * omega.cpu().numpy()).sum(1) @ mesh.area_faces
    if flux < 0:
        faces = faces[:, ::-1].copy()

    zipped = 0
    if tube > 0:
        new_v, new_f = [verts], [faces]
        borders = border_loops(faces)
        for loop in loops:
            dense = _densify_loop(loop, voxel)
            # the border that runs along this loop: it winds once around Γ's parameter (holes in the
            # surface do not) and stays within a few tube radii of it
            along = [b for b in borders if _follows_loop(verts[b], loop, max_distance=5 * tube)]
            if len(along) != 1:
                log.warning("Γ loop with %d vertices: %d cut border loops run along it (need 1); left open.",
                            len(loop), len(along))
                continue
            added_v, added_f = zip_to_loop(np.concatenate(new_v), along[0], dense)
            new_v.append(added_v)
            new_f.append(added_f)
            zipped += 1
        verts, faces = np.concatenate(new_v), np.concatenate(new_f)
    mesh = trimesh.Trimesh(verts, faces, process=True)
    mesh.update_faces(mesh.nondegenerate_faces())
    mesh.remove_unreferenced_vertices()
    return MeshingResult(mesh, level if theta is None else theta, bounds, voxel, tube, zipped)


@torch.no_grad()
def extract_curve_2d(
    current, resolution: int = 256, delta: float = 5e-3, boundary_tube: float = 0.03, min_alignment: float = 0.5,
    chunk_size: int = 1 << 16,
) -> list[np.ndarray]:
    """The curve of a 2D current: the level set f = s (s = mean of f near the boundary points), kept where
    |ω| ≥ δ and cos(ω, ∇f) ≥ ``min_alignment`` (see ``extract_surface``), cut at distance τ from the points
    and joined to them by straight segments.

    Returns a list of polylines, each (K, 2).
    """
    dev = _device(current)
    axis = np.linspace(-1.0, 1.0, resolution + 1)
    h = axis[1] - axis[0]
    grid = np.stack(np.meshgrid(axis, axis, indexing="ij"), -1).reshape(-1, 2)
    f = current.evaluate(torch.as_tensor(grid, dtype=torch.float32, device=dev), chunk_size, omega=False)
    vol = f.cpu().numpy().reshape(len(axis), len(axis))
    poles = current.poles.cpu().double().numpy()
    tube = max(boundary_tube, 1.5 * h)
    ring = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    around = (poles[:, None, :] + 0.5 * tube * np.stack([np.cos(ring), np.sin(ring)], -1)).reshape(-1, 2)
    level = float(current.evaluate(torch.as_tensor(around, dtype=torch.float32, device=dev), omega=False).mean())
    curves = []
    for contour in find_contours(vol, level):
        pts = contour * h - 1.0
        dist = np.linalg.norm(pts[:, None] - poles[None], axis=-1).min(1)
        mid = 0.5 * (pts[1:] + pts[:-1])
        mid_t = torch.as_tensor(mid, dtype=torch.float32, device=dev)
        _, omega = current.evaluate(mid_t)
        grad_f = omega - current.alpha(mid_t)
        # as in 3D: on the curve the current flows along ∇f; on the complementary level curve it does not
        cos = (omega * grad_f).sum(-1) / (omega.norm(dim=-1) * grad_f.norm(dim=-1)).clamp_min(1e-30)
        carries = ((omega.norm(dim=-1) >= delta) & (cos >= min_alignment)).cpu().numpy()
        good = carries & (dist[1:] >= tube) & (dist[:-1] >= tube)
        # split into runs of good segments
        idx = np.flatnonzero(good)
        if len(idx) == 0:
            continue
        runs = np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1)
        for run in runs:
            piece = pts[run[0]: run[-1] + 2]
            joined = 0
            for end in (0, -1):  # join ends that stopped at the tube to their pole
                d = np.linalg.norm(poles - piece[end], axis=1)
                if d.min() < 1.5 * tube:
                    p = poles[d.argmin()][None]
                    piece = np.concatenate([p, piece]) if end == 0 else np.concatenate([piece, p])
                    joined += 1
            if joined:  # the current's curve ends on the boundary points; loose pieces are level-set debris
                curves.append(piece)
    return curves
