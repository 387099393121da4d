"""Polishing a minimal surface's mesh: the current finds which surface Γ bounds, a mesh flow finds its last digits.

The extracted mesh has the right topology and lies within a few tenths of a percent of the minimal area; what is
left is a discretisation problem, solved the way mesh solvers (Brakke's Surface Evolver) solve it:

1. holes whose border is not on Γ (Γ piercing the surface, a tear) are filled, so the only border is Γ; the border
   vertices are snapped onto Γ's polyline (in float64) and stay fixed from then on;
2. level 1: the interior is remeshed isotropically to edges of length h (Botsch–Kobbelt, ``gpytoolbox``; the border
   is kept), then moved by Pinkall–Polthier's iteration: X ← argmin of the Dirichlet energy in the cotangent
   metric of the current mesh, Γ fixed (one sparse solve per step), until the area changes by less than
   ``tolerance`` relatively; the fixed point is a discrete minimal surface;
3. levels 2, 3, …: each face split in four (midpoints: a border edge's midpoint is on Γ's segment), then the flow;
4. the area A(h) ≈ A + c·h² is extrapolated over the levels (Richardson): R_k = A_k + (A_k − A_{k−1})/3, with
   |R_L − R_{L−1}| as its estimated error (the last correction A_L − R_L where only two levels are): the area of
   the minimal surface spanning Γ's polyline;
5. Γ's polyline, inscribed in the smooth curve it samples, spans an area short by c'·s² (s its spacing: 1e-4 at 300
   vertices): the levels run once more with the border on the polygon of Γ's every other vertex, and
   R(s) + (R(s) − R(2s))/3 is the area for the smooth curve (``curve_extrapolated``; a polygon whose added vertices
   are collinear gives R(2s) = R(s), no change).

The flow cannot change the topology, but a surface that is not a stable minimum of its topology does not settle:
a neck thins towards a pinch, a handle closes. Then (or where a level's faces degenerate or the remesher changes
the surface) the polish stops and says so in one sentence, and the unpolished mesh stays the result.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np
import trimesh

from deepcurrents.eval.meshing.border import triangle_areas
from deepcurrents.geometry.polyline import closed_loop_segments, closest_on_segments
from deepcurrents.geometry.topology import SurfaceTopology, border_edges, border_loops, surface_topology

log = logging.getLogger(__name__)

# a border vertex farther than this share of Γ's extent from Γ is on a hole's border, not on Γ
ON_CURVE = 1e-6
# a level's flow that still lowers the area by more than this share a step at its last step has not settled (a neck
# pinching, a handle closing, at ~1e-2 a step); redistributing a settled surface's vertices lowers it far less
UNSETTLED = 1e-4
# faces below this share of the mean face area are degenerate (a pinched neck)
DEGENERATE = 1e-8


@dataclass(frozen=True)
class PolishSettings:
    """``evaluation.mesh.polish`` (documented in ``experiments.schema.Polish``)."""

    enabled: bool = True
    edge_length: float = 0.025
    levels: int = 3
    tolerance: float = 1e-6
    max_iterations: int = 100
    remesh_iterations: int = 10
    curve_extrapolation: bool = True


def polish_settings(mesh_options: dict | None, **overrides) -> PolishSettings | None:
    """``PolishSettings`` from a run's ``evaluation.mesh`` (its ``polish`` group), with ``overrides``; None where the
    polish is off (``enabled: false``)."""
    options = {**dict(dict(mesh_options or {}).get("polish") or {}), **overrides}
    return PolishSettings(**options) if options.pop("enabled", True) else None


@dataclass
class PolishResult:
    """The finest level's mesh (the unpolished one where the polish stopped: ``stopped`` says why), the discrete
    minimal area at each level (coarse to fine, their edge lengths ``edge_lengths``), the extrapolated area and
    its estimated error, the surface's topology, the holes filled and the time taken."""

    mesh: trimesh.Trimesh
    areas: list[float] = field(default_factory=list)
    edge_lengths: list[float] = field(default_factory=list)
    extrapolated: float | None = None
    extrapolated_error: float | None = None
    topology: SurfaceTopology | None = None
    stopped: str | None = None
    holes_filled: int = 0
    iterations: list[int] = field(default_factory=list)
    seconds: float = 0.0
    level_seconds: list[float] = field(default_factory=list)  # seconds from the start to each level's end
    curve_extrapolated: float | None = None
    curve_extrapolated_error: float | None = None

    @property
    def area(self) -> float:
        """The finest level's area (the plain mesh's where the polish stopped)."""
        return self.areas[-1] if self.areas and self.stopped is None else float(self.mesh.area)

    @property
    def area_error(self) -> float | None:
        """The finest level's estimated discretisation error, |A_L − R_L| (None below two levels)."""
        if self.extrapolated is None or self.stopped is not None:
            return None
        return abs(self.areas[-1] - self.extrapolated)


def pinkall_polthier(vertices: np.ndarray, faces: np.ndarray, fixed: np.ndarray, tolerance: float = 1e-8,
                     max_iterations: int = 100) -> tuple[np.ndarray, list[float]]:
    """Pinkall–Polthier's minimal-surface iteration: X_{k+1} minimises Σ_edges w_ij(X_k) |x_i − x_j|², w the
    cotangent weights of the mesh at X_k, with the vertices ``fixed`` held; stops when the area changes by less
    than ``tolerance`` relatively in a step, or after ``max_iterations``.

    vertices (V, 3) float64, faces (F, 3), fixed (K,) indices → (vertices (V, 3), the area after each step, the
    starting area first). Stops early, without the step, where the cotangent weights are not finite (degenerate
    faces)."""
    import igl
    from scipy.sparse.linalg import splu

    x = np.array(vertices, dtype=np.float64)
    faces = np.ascontiguousarray(faces, dtype=np.int64)
    free = np.setdiff1d(np.arange(len(x)), fixed)
    areas = [float(triangle_areas(x, faces).sum())]
    for _ in range(max_iterations):
        laplacian = -igl.cotmatrix(x, faces).tocsr()  # positive semidefinite: Σ w_ij on the diagonal
        if not np.isfinite(laplacian.data).all():
            break
        inner = laplacian[free][:, free].tocsc()
        rhs = -(laplacian[free][:, fixed] @ x[fixed])
        try:
            step = splu(inner).solve(rhs)
        except RuntimeError:  # singular: a pinched piece
            break
        if not np.isfinite(step).all():
            break
        x[free] = step
        areas.append(float(triangle_areas(x, faces).sum()))
        if abs(areas[-2] - areas[-1]) <= tolerance * areas[-1]:
            break
    return x, areas


def richardson(areas: list[float]) -> tuple[float | None, float | None]:
    """The area extrapolated from levels whose edge length halves each time (A(h) ≈ A + c·h²), and its estimated
    error: (R_L, |R_L − R_{L−1}|) over three levels or more, (R_L, |A_L − R_L|) over two, (None, None) below."""
    if len(areas) < 2:
        return None, None
    r = [a + (a - b) / 3.0 for b, a in zip(areas[:-1], areas[1:], strict=True)]
    return r[-1], abs(r[-1] - r[-2]) if len(r) > 1 else abs(areas[-1] - r[-1])


def fill_holes_off_curve(vertices: np.ndarray, faces: np.ndarray, loops: list[np.ndarray], tolerance: float
                         ) -> tuple[np.ndarray, np.ndarray, int]:
    """Fills each border loop of the mesh with a vertex farther than ``tolerance`` from Γ (loops (M_i, 3)) by a fan
    to its centroid, so that the only border left is on Γ. → (vertices, faces, holes filled)."""
    starts, ends, _ = closed_loop_segments(loops)
    new_vertices, new_faces, filled = [vertices], [faces], 0
    for loop in border_loops(faces):
        if closest_on_segments(vertices[loop], starts, ends)[0].max() <= tolerance:
            continue
        centre = len(vertices) + filled
        new_vertices.append(vertices[loop].mean(0, keepdims=True))
        # the border runs along its faces' orientation, so the fan runs against it
        new_faces.append(np.stack([np.roll(loop, -1), loop, np.full(len(loop), centre)], 1))
        filled += 1
    return np.concatenate(new_vertices), np.concatenate(new_faces), filled


@dataclass
class LevelOne:
    """Step 1 and the remeshing of step 2 (module docstring): the mesh the flow starts from, its edge length h, the
    surface's topology, the holes filled, and why there is none (``stopped``)."""

    vertices: np.ndarray
    faces: np.ndarray
    edge_length: float
    topology: SurfaceTopology | None
    holes_filled: int = 0
    stopped: str | None = None


def level_one_mesh(mesh: trimesh.Trimesh, loops: list[np.ndarray], settings: PolishSettings) -> LevelOne:
    """The extracted mesh with its holes off Γ filled, its border snapped onto Γ and its interior remeshed to edges
    of ``settings.edge_length`` × Γ's largest extent (the start of the flow; also Surface Evolver's in
    ``benchmarks/polish_vs_evolver.py``). mesh: border on Γ; loops (M_i, 3) float64 in the mesh's units."""
    import gpytoolbox

    vertices = np.array(mesh.vertices, dtype=np.float64)
    faces = np.array(mesh.faces, dtype=np.int64)
    if len(faces) == 0:
        return LevelOne(vertices, faces, 0.0, None, stopped="the mesh is empty")
    points = np.concatenate(loops)
    extent = float((points.max(0) - points.min(0)).max())
    vertices, faces, filled = fill_holes_off_curve(vertices, faces, loops, ON_CURVE * extent)
    if filled:
        log.info("Polish: filled %d hole(s) of the mesh whose border is not on Γ.", filled)
    topology = surface_topology(faces)
    h = settings.edge_length * extent
    if not topology.manifold:
        return LevelOne(vertices, faces, h, topology, filled, "the extracted mesh is not an oriented manifold")
    starts, ends, _ = closed_loop_segments(loops)
    border = np.unique(border_edges(faces))
    vertices[border] = closest_on_segments(vertices[border], starts, ends)[1]
    try:
        vertices, faces = gpytoolbox.remesh_botsch(vertices, faces, settings.remesh_iterations, h, True)
    except (RuntimeError, ValueError) as err:  # the library's refusal of a mesh it cannot remesh
        return LevelOne(vertices, faces, h, topology, filled, f"the remesher failed ({err})")
    faces = np.asarray(faces, dtype=np.int64)
    stopped = None
    if (remeshed := surface_topology(faces)) != topology:
        stopped = (f"the remesher changed the surface from {topology.describe()} to {remeshed.describe()} "
                   "(edge_length too coarse for a thin neck?)")
    return LevelOne(vertices, faces, h, topology, filled, stopped)


def polish_minimal_surface(mesh: trimesh.Trimesh, loops: list[np.ndarray], settings: PolishSettings | None = None
                           ) -> PolishResult:
    """The polished mesh of a minimal surface spanning Γ (see the module docstring).

    Args:
        mesh: the extracted mesh, its border on Γ (``extract_surface``), any units.
        loops: Γ as (M_i, 3) float64 polylines in the mesh's units.
        settings: the level-1 edge length as a share of Γ's largest extent, the number of levels, the flow's
            relative area tolerance and step limit per level, the remesher's iterations, and whether to
            extrapolate in Γ's sampling too.
    """
    settings = settings or PolishSettings()
    began = time.perf_counter()
    result = PolishResult(mesh=mesh)
    start = level_one_mesh(mesh, loops, settings)
    result.topology, result.holes_filled, result.stopped = start.topology, start.holes_filled, start.stopped
    if start.stopped:
        return _finish(result, began)
    vertices, faces, _, why = _flow(start.vertices, start.faces, settings, start.edge_length, result, began)
    if why:
        result.stopped = why
        return _finish(result, began)
    result.mesh = trimesh.Trimesh(vertices, faces, process=False)
    result.extrapolated, result.extrapolated_error = richardson(result.areas)
    if settings.curve_extrapolation and all(len(lp) >= 8 for lp in loops):
        _extrapolate_in_the_curve(result, (start.vertices, start.faces), loops, settings, start.edge_length)
    return _finish(result, began)


def _flow(vertices: np.ndarray, faces: np.ndarray, settings: PolishSettings, h: float, result: PolishResult | None
          = None, began: float | None = None) -> tuple[np.ndarray, np.ndarray, list[float], str | None]:
    """Steps 2–3 of the module docstring from a level-1 mesh of edges ``h``: the flow on each level, its areas,
    edge lengths, steps and seconds since ``began`` (``time.perf_counter``) appended to ``result`` where given.
    → (the finest level's vertices, faces, each level's area, why the flow stopped or None)."""
    import igl

    level_areas = []
    for level in range(settings.levels):
        if level:
            vertices, faces = igl.upsample(vertices, faces)
            h /= 2.0
        fixed = np.unique(border_edges(faces))
        vertices, areas = pinkall_polthier(vertices, faces, fixed, settings.tolerance, settings.max_iterations)
        why = _unsettled(vertices, faces, areas)
        if why:
            return vertices, faces, level_areas, f"at level {level + 1} (edges {h:.3g}) {why}"
        level_areas.append(areas[-1])
        if result is not None:
            result.areas.append(areas[-1])
            result.edge_lengths.append(h)
            result.iterations.append(len(areas) - 1)
            result.level_seconds.append(time.perf_counter() - began)
    return vertices, faces, level_areas, None


def every_other_vertex(points: np.ndarray, loop: np.ndarray) -> np.ndarray:
    """Points on a closed polyline (n, 3) moved onto the polygon of its every other vertex (0, 2, 4, …; for odd n
    the last side spans one segment), at the same share of arc length between the two kept vertices.
    points (P, 3) on the loop → (P, 3)."""
    n = len(loop)
    ends = np.roll(loop, -1, 0)
    _, _, segment = closest_on_segments(points, loop, ends)
    lengths = np.linalg.norm(ends - loop, axis=1)
    arc = np.concatenate([[0.0], np.cumsum(lengths)])  # arc[j]: arc length at vertex j; arc[n]: the whole loop
    along = arc[segment] + np.linalg.norm(points - loop[segment], axis=1)
    first = segment - segment % 2
    last = np.minimum(first + 2, n)  # index n is vertex 0 again
    share = (along - arc[first]) / (arc[last] - arc[first])
    return (1 - share)[:, None] * loop[first] + share[:, None] * loop[last % n]


def _extrapolate_in_the_curve(result: PolishResult, level_one: tuple[np.ndarray, np.ndarray], loops: list[np.ndarray],
                              settings: PolishSettings, h: float) -> None:
    """``curve_extrapolated``: the area extrapolated in Γ's sampling too (step 5 of the module docstring): the
    levels once more with the border on the polygon of Γ's every other vertex, R(2s), then R(s) + (R(s) − R(2s))/3;
    its error: the two extrapolations' errors, the coarse one's a third."""
    vertices, faces = np.array(level_one[0]), level_one[1]
    border = np.unique(border_edges(faces))
    starts, ends, owner = closed_loop_segments(loops)
    which = owner[closest_on_segments(vertices[border], starts, ends)[2]]
    for i, loop in enumerate(loops):
        on = border[which == i]
        vertices[on] = every_other_vertex(vertices[on], loop)
    _, _, coarse_areas, why = _flow(vertices, faces, settings, h)
    if why or len(coarse_areas) < 2:
        return
    coarse_value, coarse_error = richardson(coarse_areas)
    fine = result.extrapolated
    result.curve_extrapolated = fine + (fine - coarse_value) / 3.0
    result.curve_extrapolated_error = result.extrapolated_error + coarse_error / 3.0


def _unsettled(vertices: np.ndarray, faces: np.ndarray, areas: list[float]) -> str | None:
    """Why a level's flow is no discrete minimal surface of the mesh's topology, or None where it settled."""
    face_areas = triangle_areas(vertices, faces)
    if not np.isfinite(face_areas).all() or face_areas.min() < DEGENERATE * face_areas.mean():
        return "faces collapsed: the flow pinched a neck or closed a handle"
    if len(areas) < 2:
        return "the flow could not take a step (degenerate faces)"
    last = abs(areas[-2] - areas[-1]) / areas[-1]
    if last > UNSETTLED:
        return (f"the area still fell by {last:.2g} a step after {len(areas) - 1} steps: the surface is no stable "
                "minimum of its topology (a neck pinching or a handle closing)")
    return None


def _finish(result: PolishResult, began: float) -> PolishResult:
    result.seconds = time.perf_counter() - began
    if result.stopped:
        log.warning("The mesh was not polished: %s; the unpolished mesh is kept.", result.stopped)
    return result
