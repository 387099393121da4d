"""Target surfaces Σ for reconstruction (paper §4.2–4.3): closest points, normals, uniform surface samples,
and the per-sample metric B_x = w_x (I − n nᵀ) of the current loss.

Everything here takes plain arrays and keeps no state between calls, so DataModules (in loader workers)
and the families engineer's augmentation (a deformed mesh every step) can call it freely:

- :func:`mesh_boundary_loops`: Γ of a mesh, oriented with its face normals (Stokes: the loops follow the
  faces' directed edges), which is the orientation the paper's surface-loss sign expects.
- :func:`closest_points_on_mesh`: exact closest points through libigl's AABB tree.
- :func:`reconstruction_sample`: one batch {"x", "metric", "surface_points", "surface_normals", "epsilon"}.
- :class:`MeshTarget` / :class:`PointCloudTarget`: the same for a fixed target, with its tree built once.

Orientation check: for a flat disk with normal +z and its Stokes-oriented rim, the ideal
f = −alpha_scale·Ω_Γ drops by 4π·alpha_scale ≈ 0.0126 > δ = 0.01 from y − εn to y + εn, so the surface
hinge loss (δ − f(y − εn) + f(y + εn))^+ can reach zero; the reversed rim would fight it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import igl
import numpy as np
import torch
from scipy.spatial import cKDTree

from deepcurrents.data.sampling import NearTargetSampler
from deepcurrents.errors import ConfigError
from deepcurrents.geometry.polyline import closed_loop_segments, segment_distance
from deepcurrents.geometry.topology import border_edges, border_loops

# the paper's surface-loss offsets ε ~ U[0.0199, 0.0201]: ε = 0.02 ± 0.5 %
SURFACE_EPSILON = 0.02
EPSILON_JITTER = 0.005
# A range [ε_min, ε_max] of offsets is tried in this many geometric steps from ε_max down; an offset point is
# clear when it lies on its own side of the face nearest to it and at least this fraction of ε from Σ.
EPSILON_LEVELS = 4
EPSILON_CLEARANCE = 0.25
# Barycentric tolerance for "the closest point lies on a boundary edge / vertex".
_BARY_TOL = 1e-7


def _as_numpy(a, dtype) -> np.ndarray:
    if isinstance(a, torch.Tensor):
        a = a.detach().cpu().numpy()
    return np.ascontiguousarray(np.asarray(a, dtype=dtype))


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unit normals of triangles (right-hand rule on the vertex order). (V, 3), (F, 3) → (F, 3)."""
    v = vertices[faces]
    n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    return n / np.linalg.norm(n, axis=1, keepdims=True).clip(1e-300)


def _edge_code(edges: np.ndarray, num_vertices: int) -> np.ndarray:
    """One integer per directed edge (E, 2) → (E,), for set tests with np.isin."""
    return edges[:, 0].astype(np.int64) * (num_vertices + 1) + edges[:, 1]


def mesh_boundary_loops(vertices, faces) -> list[np.ndarray]:
    """Γ of a triangle mesh: its boundary loops as (M_i, 3) float64 arrays, oriented with the faces
    (each loop walks the boundary edges in their faces' direction, i.e. Stokes' orientation for the
    right-hand-rule normals). Empty list for a closed mesh. The mesh should be edge-manifold.
    """
    v = _as_numpy(vertices, np.float64)
    f = _as_numpy(faces, np.int64)
    edges = border_edges(f)
    if len(np.unique(edges[:, 0])) < len(edges):
        # holes that touch at a vertex (two border edges leave it): libigl's walk breaks there; the edge walk
        # splits it into simple loops, each already in its faces' direction
        return [v[loop] for loop in border_loops(f)]
    loops = igl.boundary_loop_all(f)  # otherwise libigl's loops, as every run so far has had them
    if not loops:
        return []
    forward = _edge_code(edges, len(v))
    out = []
    for loop in loops:  # a handful of loops; their vertices are handled as arrays
        loop = np.asarray(loop, dtype=np.int64)
        # follow the faces: reverse when most of the loop's edges run against them
        steps = _edge_code(np.stack([loop, np.roll(loop, -1)], 1), len(v))
        if np.isin(steps, forward).sum() < len(loop) / 2:
            loop = loop[::-1]
        out.append(v[loop])
    return out


def closest_points_on_mesh(points, vertices, faces, tree: igl.AABB | None = None):
    """Exact closest points on a triangle mesh (libigl AABB tree).

    points (N, 3), vertices (V, 3), faces (F, 3); ``tree`` a prebuilt ``igl.AABB`` of (V, F) (built here
    when None). → (squared distances (N,), closest face index (N,), closest points (N, 3)), float64 numpy.
    """
    p = _as_numpy(points, np.float64)
    v = _as_numpy(vertices, np.float64)
    f = _as_numpy(faces, np.int64)
    if tree is None:
        return igl.point_mesh_squared_distance(p, v, f)
    return tree.squared_distance(v, f, p)


def sample_mesh_surface(vertices: np.ndarray, faces: np.ndarray, num: int, generator: torch.Generator,
                        vertex_normals: np.ndarray | None = None, areas: np.ndarray | None = None):
    """Uniform (by area) points on a mesh with their normals (barycentric interpolation of vertex normals,
    normalised, as the authors did: smoother than face normals for the ε offsets).

    → (points (num, 3), normals (num, 3)) float64 numpy.
    """
    if areas is None:
        areas = 0.5 * igl.doublearea(vertices, faces)
    if vertex_normals is None:
        vertex_normals = igl.per_vertex_normals(vertices, faces)
    face = torch.multinomial(torch.as_tensor(areas, dtype=torch.float64), num, replacement=True,
                             generator=generator).numpy()
    # uniform barycentrics on a triangle: (1 − √r1, √r1(1 − r2), √r1 r2)
    r = torch.rand(num, 2, generator=generator, dtype=torch.float64).numpy()
    s = np.sqrt(r[:, 0])
    bary = np.stack([1.0 - s, s * (1.0 - r[:, 1]), s * r[:, 1]], 1)
    tri = faces[face]
    points = np.einsum("nk,nkd->nd", bary, vertices[tri])
    normals = np.einsum("nk,nkd->nd", bary, vertex_normals[tri])
    # a flat-folded spot can cancel the interpolated normal; fall back to the face normal there
    norm = np.linalg.norm(normals, axis=1, keepdims=True)
    bad = norm[:, 0] < 1e-8
    if bad.any():
        normals[bad] = face_normals(vertices, tri[bad])
        norm[bad] = 1.0
    return points, normals / norm


def reconstruction_metric(normals: torch.Tensor, on_boundary: torch.Tensor,
                          weights: torch.Tensor) -> torch.Tensor:
    """B_x = w_x (I − n nᵀ), and w_x I where ``on_boundary`` (the closest point of Σ lies on Γ, the authors'
    code; :func:`target_sample` also marks points beyond ``metric_band`` this way).

    normals (N, 3) unit; on_boundary (N,) bool; weights (N,) → (N, 3, 3).
    """
    eye = torch.eye(3, dtype=normals.dtype, device=normals.device).expand(len(normals), 3, 3)
    n = torch.where(on_boundary.unsqueeze(-1), torch.zeros_like(normals), normals)
    return weights[:, None, None] * (eye - n.unsqueeze(-1) * n.unsqueeze(-2))


def distance_to_loops(x, loops: list[np.ndarray]) -> np.ndarray:
    """Euclidean distance |x − proj_Γ(x)| to closed polygonal loops, exact (``segment_distance``: libigl's AABB
    tree on Γ's segments, a few times faster than the brute-force ``project_to_segments`` for thousands of points).

    x (N, 3), loops [(M_i, 3)] → (N,) float64.
    """
    starts, ends, _ = closed_loop_segments(loops)
    return segment_distance(_as_numpy(x, np.float64), starts, ends)


def boundary_weights(x: torch.Tensor, loops: list[np.ndarray], sigma: float,
                     enabled: bool = True) -> torch.Tensor:
    """w_x: exp(−|x − proj_Γ(x)|² / 2σ²) on the first half of the samples, 1 on the second half (paper §4.2),
    normalised to mean 1 so that E_x w|Bω| is the authors' Σ w|Bω| / Σ w. All ones when disabled.

    x (N, 3) → (N,) float32.
    """
    n = x.shape[0]
    w = torch.ones(n, dtype=torch.float64)
    if not enabled or n == 0:
        return w.float()
    half = n // 2
    d = torch.as_tensor(distance_to_loops(x[:half], loops))
    w[:half] = torch.exp(-(d * d) / (2.0 * sigma * sigma))
    return (w * (n / w.sum())).float()


@dataclass
class Closest:
    """Closest points of queries on a target: point (N, 3), unit normal (N, 3), on_boundary (N,) bool."""

    point: np.ndarray
    normal: np.ndarray
    on_boundary: np.ndarray


class MeshTarget:
    """A triangle-mesh target Σ with Γ = its boundary loops (or given ``loops``); AABB tree built once.

    vertices (V, 3), faces (F, 3). "On Γ" is exact: the closest point lies on a boundary edge or is a
    boundary vertex (barycentric test), so it does not depend on the loops' sampling.
    """

    def __init__(self, vertices, faces, loops: list[np.ndarray] | None = None,
                 topology: tuple[np.ndarray, np.ndarray] | None = None):
        """``topology``: (edge_on_boundary (F, 3), vertex_on_boundary (V,)) of these faces if already known
        (``moved``); they depend on the faces alone, and finding the border edges is much of building a target."""
        self.vertices = _as_numpy(vertices, np.float64)
        self.faces = _as_numpy(faces, np.int64)
        self.loops = [np.asarray(lp, np.float64) for lp in loops] if loops is not None else \
            mesh_boundary_loops(self.vertices, self.faces)
        self.tree = igl.AABB()
        self.tree.init(self.vertices, self.faces)
        self.face_normals = face_normals(self.vertices, self.faces)
        self.vertex_normals = igl.per_vertex_normals(self.vertices, self.faces)
        self.areas = 0.5 * igl.doublearea(self.vertices, self.faces)
        if topology is None:
            # edge k of a face is the one opposite its vertex k
            edges = border_edges(self.faces)
            f = self.faces
            opposite = np.stack([f[:, [1, 2]], f[:, [2, 0]], f[:, [0, 1]]], 1)  # (F, 3, 2)
            nv = len(self.vertices)
            edge_on_boundary = np.isin(_edge_code(np.sort(opposite.reshape(-1, 2), 1), nv),
                                       _edge_code(np.sort(edges, 1), nv)).reshape(-1, 3)
            vertex_on_boundary = np.zeros(len(self.vertices), bool)
            vertex_on_boundary[edges.reshape(-1)] = True
            topology = (edge_on_boundary, vertex_on_boundary)
        self.edge_on_boundary, self.vertex_on_boundary = topology

    def moved(self, vertices, loops: list[np.ndarray]) -> MeshTarget:
        """The same faces with other vertex positions (an augmented copy of this mesh, (V, 3)) and its loops:
        tree, normals and areas are rebuilt, the border (which depends on the faces alone) is reused."""
        return MeshTarget(vertices, self.faces, loops, topology=(self.edge_on_boundary, self.vertex_on_boundary))

    @property
    def area(self) -> float:
        return float(self.areas.sum())

    def closest(self, x: np.ndarray) -> Closest:
        """Closest points, their face normals and whether they lie on Γ. x (N, 3)."""
        _, face, point = self.tree.squared_distance(self.vertices, self.faces, _as_numpy(x, np.float64))
        tri = self.faces[face]
        v = self.vertices
        bary = igl.barycentric_coordinates(point, v[tri[:, 0]], v[tri[:, 1]], v[tri[:, 2]])
        on_edge = (bary < _BARY_TOL) & self.edge_on_boundary[face]
        on_vertex = (bary > 1.0 - _BARY_TOL) & self.vertex_on_boundary[tri]
        return Closest(point, self.face_normals[face], (on_edge | on_vertex).any(1))

    def sample_surface(self, num: int, generator: torch.Generator) -> tuple[np.ndarray, np.ndarray]:
        """Uniform points on Σ and their normals. → ((num, 3), (num, 3))."""
        return sample_mesh_surface(self.vertices, self.faces, num, generator, self.vertex_normals, self.areas)

    def sample(self, num_ambient: int, num_surface: int, generator: torch.Generator, **kwargs) -> dict:
        return target_sample(self, num_ambient, num_surface, generator, **kwargs)


class PointCloudTarget:
    """An oriented point cloud target: points (P, 3) with normals (P, 3) and Γ given as loops.

    Closest points are the nearest cloud points (scipy KD-tree). "On Γ" means Γ is no farther than the
    nearest cloud point plus half the cloud's typical spacing (the nearest part of Σ is its rim).
    """

    def __init__(self, points, normals, loops: list[np.ndarray]):
        self.points = _as_numpy(points, np.float64)
        normals = _as_numpy(normals, np.float64)
        self.normals = normals / np.linalg.norm(normals, axis=1, keepdims=True).clip(1e-300)
        self.loops = [np.asarray(lp, np.float64) for lp in loops]
        self.tree = cKDTree(self.points)
        k = min(2, len(self.points))
        d, _ = self.tree.query(self.points, k=k)
        self.spacing = float(np.median(d[:, -1])) if k > 1 else 0.0

    def closest(self, x: np.ndarray) -> Closest:
        x = _as_numpy(x, np.float64)
        dist, idx = self.tree.query(x)
        d_gamma = distance_to_loops(x, self.loops)
        return Closest(self.points[idx], self.normals[idx], d_gamma <= dist + 0.5 * self.spacing)

    def sample_surface(self, num: int, generator: torch.Generator) -> tuple[np.ndarray, np.ndarray]:
        idx = torch.randint(len(self.points), (num,), generator=generator).numpy()
        return self.points[idx], self.normals[idx]

    def sample(self, num_ambient: int, num_surface: int, generator: torch.Generator, **kwargs) -> dict:
        return target_sample(self, num_ambient, num_surface, generator, **kwargs)


def surface_epsilon_range(value, name: str = "data.surface_epsilon") -> tuple[float, float]:
    """The surface loss's offset as (ε_min, ε_max): a distance ε gives (ε, ε); a pair [ε_min, ε_max] asks for the
    largest ε in it at which a sample's offsets stay clear of the rest of Σ (:func:`clear_surface_epsilon`).
    ConfigError, naming ``name``, for anything but distances 0 < ε_min ≤ ε_max < 1."""
    many = isinstance(value, Sequence) and not isinstance(value, str)  # a list, a tuple or an OmegaConf ListConfig
    pair = list(value) if many else [value, value]
    ok = len(pair) == 2 and all(isinstance(e, (int, float)) and not isinstance(e, bool) for e in pair)
    if not ok or not 0 < pair[0] <= pair[1] < 1:
        shown = list(value) if many else value
        raise ConfigError(f"{name}={shown!r} must be a distance in (0, 1) or a range [min, max] of them with min ≤ "
                          "max (the domain is [-1, 1]^3; the paper's is 0.02).")
    return float(pair[0]), float(pair[1])


def clear_surface_epsilon(target: MeshTarget | PointCloudTarget, points: np.ndarray, normals: np.ndarray,
                          low: float, high: float, levels: int = EPSILON_LEVELS,
                          clearance: float = EPSILON_CLEARANCE) -> np.ndarray:
    """Per surface sample, the largest ε of ``levels`` geometric steps from ``high`` down to ``low`` at which both
    offset points y ± εn are clear: each lies on its own side of the face nearest to it (y − εn behind it,
    y + εn in front) and at least ``clearance``·ε from Σ. A larger ε is a gentler slope δ / 2ε for the surface
    hinge (a lower crispness, mostly by a weaker sheet: docs/experiments/families.md), but across a finger thinner
    than ε, or into its neighbour, the offset point lands on the wrong side of another sheet and the hinge asks f
    to fill the gap (a mitten). Samples clear at no step keep ``low``.

    points, normals (M, 3) → ε (M,) float64. Costs up to 2·levels closest-point queries per sample (only the
    samples not yet settled are queried again)."""
    points, normals = _as_numpy(points, np.float64), _as_numpy(normals, np.float64)
    eps = np.full(len(points), low)
    pending = np.arange(len(points))
    for e in np.geomspace(high, low, levels)[:-1] if high > low else []:
        if len(pending) == 0:
            break
        side = np.repeat([-1.0, 1.0], len(pending))[:, None]  # y − εn for every pending sample, then y + εn
        q = np.tile(points[pending], (2, 1)) + side * e * np.tile(normals[pending], (2, 1))
        near = target.closest(q)  # one query for both sides
        d = q - near.point
        ok = (side[:, 0] * np.einsum("nd,nd->n", d, near.normal) > 0) & (np.linalg.norm(d, axis=1) >= clearance * e)
        clear = ok[: len(pending)] & ok[len(pending):]
        eps[pending[clear]] = e
        pending = pending[~clear]
    return eps


def target_sample(target: MeshTarget | PointCloudTarget, num_ambient: int, num_surface: int,
                  generator: torch.Generator, boundary_sigma: float = 0.1, boundary_weighting: bool = True,
                  surface_loss: bool = True, domain: float = 1.0,
                  ambient: NearTargetSampler | None = None,
                  metric_band: float | None = None,
                  surface_epsilon: float | tuple[float, float] = SURFACE_EPSILON) -> dict[str, torch.Tensor]:
    """One training batch for a target (see :func:`reconstruction_sample`). ``ambient``: where the ambient
    samples come from (None: uniform in [-domain, domain]^3, the paper's; a ``NearTargetSampler``: a
    mixture concentrated near Σ whose importance weights are folded into the metric, B_x ← w_imp B_x, so
    the current loss keeps its expectation). ``metric_band`` (beyond the paper; None: off): points farther
    than this from Σ get the Euclidean metric w_x I, since the target current vanishes there; the paper's
    w_x (I − n nᵀ) leaves ω along n free everywhere, and a small network fills that freedom with fog.
    ``surface_epsilon``: the surface loss's offsets ε ~ U[(1 − 0.005) ε, (1 + 0.005) ε] (the paper's 0.02); a range
    [ε_min, ε_max] (beyond the paper): each sample's ε is the largest in it that stays clear of the rest of Σ
    (:func:`clear_surface_epsilon`), with the same ± 0.5 %."""
    eps_low, eps_high = surface_epsilon_range(surface_epsilon)
    if ambient is None:
        x = (torch.rand(num_ambient, 3, generator=generator, dtype=torch.float64) * 2.0 - 1.0) * domain
        importance = None
    else:
        x, importance = ambient.sample(num_ambient, generator)
        # shuffled, so that the boundary weighting's half (the first) holds both kinds of sample
        order = torch.randperm(num_ambient, generator=generator)
        x, importance = x[order], importance[order]
    near = target.closest(x.numpy())
    w = boundary_weights(x, target.loops, boundary_sigma, boundary_weighting)
    if importance is not None:
        # w_x's mean over U stays 1 (its importance-weighted batch mean), then the importance weights
        w = (w.double() * importance * (importance.sum() / (w.double() * importance).sum())).float()
    euclidean = near.on_boundary
    if metric_band is not None:
        euclidean = euclidean | (np.linalg.norm(x.numpy() - near.point, axis=1) > metric_band)
    metric = reconstruction_metric(torch.as_tensor(near.normal, dtype=torch.float32),
                                   torch.as_tensor(euclidean), w)
    batch = {"x": x.float(), "metric": metric}
    if surface_loss and num_surface > 0:
        pts, nrm = target.sample_surface(num_surface, generator)
        batch["surface_points"] = torch.as_tensor(pts, dtype=torch.float32)
        batch["surface_normals"] = torch.as_tensor(nrm, dtype=torch.float32)
        base = eps_high if eps_low == eps_high else \
            torch.as_tensor(clear_surface_epsilon(target, pts, nrm, eps_low, eps_high))
        lo, hi = base * (1.0 - EPSILON_JITTER), base * (1.0 + EPSILON_JITTER)
        batch["epsilon"] = (lo + (hi - lo) * torch.rand(num_surface, generator=generator, dtype=torch.float64)).float()
    return batch


def closest_point_sample(target: MeshTarget | PointCloudTarget, num_ambient: int, num_near: int,
                         generator: torch.Generator, near_sigma: float = 0.05,
                         domain: float = 1.0) -> dict[str, torch.Tensor]:
    """Training pairs for the closest-surface-point baseline (Venkatesh et al. 2021): points x, uniform in
    the domain and near Σ (surface samples + N(0, near_sigma²) noise), with their closest points on Σ.

    → {"x": (N + M, 3), "closest": (N + M, 3)} float32.
    """
    x = (torch.rand(num_ambient, 3, generator=generator, dtype=torch.float64) * 2.0 - 1.0) * domain
    if num_near > 0:
        pts, _ = target.sample_surface(num_near, generator)
        noise = torch.randn(num_near, 3, generator=generator, dtype=torch.float64) * near_sigma
        x = torch.cat([x, torch.as_tensor(pts) + noise]).clamp(-domain, domain)
    near = target.closest(x.numpy())
    return {"x": x.float(), "closest": torch.as_tensor(near.point, dtype=torch.float32)}


def reconstruction_sample(vertices, faces, loops: list[np.ndarray] | None, num_ambient: int,
                          num_surface: int, generator: torch.Generator, boundary_sigma: float = 0.1,
                          boundary_weighting: bool = True, surface_loss: bool = True,
                          metric_band: float | None = None) -> dict[str, torch.Tensor]:
    """One reconstruction batch for a mesh target, stateless (builds the AABB tree each call: for a mesh
    that changes every step; keep a :class:`MeshTarget` for a fixed one).

    Args:
        vertices (V, 3), faces (F, 3): the target Σ (numpy or torch).
        loops: Γ as a list of (M_i, 3) arrays; None → :func:`mesh_boundary_loops`.
        num_ambient: ambient samples x ~ U([-1, 1]^3) for the current loss.
        num_surface: uniform samples on Σ for the surface loss.
        generator: a ``torch.Generator``; all randomness comes from it.
        boundary_sigma: σ of the boundary weighting (paper 0.1).
        boundary_weighting: False → w_x = 1 everywhere (ablation).
        surface_loss: False → no surface samples in the batch (ablation).
        metric_band: None (the paper); else w_x I beyond this distance from Σ (:func:`target_sample`).

    Returns float32 tensors: "x" (N, 3); "metric" (N, 3, 3) = w_x (I − n nᵀ), w_x I where the closest point
    lies on Γ; and with the surface loss "surface_points" (M, 3), "surface_normals" (M, 3) unit,
    "epsilon" (M,) ~ U[0.0199, 0.0201].
    """
    target = MeshTarget(vertices, faces, loops)
    return target_sample(target, num_ambient, num_surface, generator, boundary_sigma=boundary_sigma,
                         boundary_weighting=boundary_weighting, surface_loss=surface_loss,
                         metric_band=metric_band)
