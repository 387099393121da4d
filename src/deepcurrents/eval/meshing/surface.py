"""``extract_surface``: the surface of a 3D current as a triangle mesh whose border lies on Γ.

Paper §5.2 marches the level set f = s and keeps the vertices where |ω| ≥ δ. Near Γ that test is
meaningless (α is singular and the network is smooth there), which leaves a ragged border and spurious
faces. Here, whatever the method (``METHODS``: the phase by default, the paper's level set):

1. the method samples its field on a grid over the region of interest (by default Γ's bounding box: a
   minimal surface lies in the convex hull of its boundary) and marching cubes extracts its level;
2. the mesh is cut exactly along the tube of radius τ around Γ (``border.cut_tube``);
3. outside the tube, faces are kept where |ω| at the centroid is ≥ δ and the method says they carry the
   current, and specks (small components) and closed bubbles (components without a border: cycles, ∂ = 0,
   which span nothing; a sheet a reconstruction metric leaves free inside a nearly closed part) are dropped;
4. vertices move onto the surface by a few clamped Newton steps of the method's residual;
5. faces are oriented along the current (ω points along the normal of the surface it represents);
6. the tube is closed: each cut border loop is zipped to its loop of Γ (``border.close_onto_loops``), so
   the mesh's border is Γ itself (of several borders along one loop, the one running the current's way;
   a cap across a reconstruction's opening is dropped). A loop that cannot be matched (the surface is
   torn near Γ) is left open and ``metrics.boundary_error`` shows it.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
import torch
import trimesh
from skimage.measure import marching_cubes

from deepcurrents.errors import ConfigError
from deepcurrents.eval.device import device_of, require_memory
from deepcurrents.eval.level_sets import reads_level_sets
from deepcurrents.eval.meshing.border import close_onto_loops, cut_tube
from deepcurrents.eval.meshing.level_set import LevelSetMethod
from deepcurrents.eval.meshing.method import MeshMethod
from deepcurrents.eval.meshing.phase import PhaseMethod
from deepcurrents.geometry.polyline import closed_loop_segments, segment_distance
from deepcurrents.geometry.topology import border_edges

log = logging.getLogger(__name__)

METHODS: dict[str, type[MeshMethod]] = {m.name: m for m in (PhaseMethod, LevelSetMethod)}
MESH_METHODS = tuple(METHODS)
MESH_METHOD_CHOICES = ("auto", *MESH_METHODS)  # what evaluation.mesh.method and the apps accept


@dataclass
class MeshingResult:
    """The extracted mesh, the level it was extracted at (f's level s for "level_set", the off-surface
    phase θ for "phase") and how many loops of Γ its border was closed onto."""

    mesh: trimesh.Trimesh
    level: float
    zipped_loops: int
    closed_area_dropped: float = 0.0  # area of the closed bubbles left out (step 3 of the module docstring)


def mesh_method(options: dict, default: str) -> dict:
    """``options`` with ``method`` "auto" (or unset) replaced by the model kind's ``default``: "phase" for
    minimal currents (ω ≈ 0 off the surface, so the phase is constant there), "level_set" for currents
    trained under a reconstruction metric (ω along the target's normal is free off the surface, which
    can turn the phase over twice: doubled sheets)."""
    options = dict(options)
    if options.get("method") in (None, "auto"):
        options["method"] = default
    return options


def region_of_interest(loops: list[np.ndarray], padding: float = 0.15, domain: float = 1.0) -> np.ndarray:
    """Γ's bounding box grown by ``padding`` × its largest extent, clipped to the domain. loops (M_i, 3)
    → (2, 3)."""
    pts = np.concatenate(loops)
    lo, hi = pts.min(0), pts.max(0)
    pad = padding * float((hi - lo).max()) + 1e-3
    return np.stack([np.maximum(lo - pad, -domain), np.minimum(hi + pad, domain)])


def mesh_region(loops: list[np.ndarray], options: dict) -> np.ndarray:
    """The region ``extract_surface(current, **options)`` meshes for a current with Γ = ``loops`` (M_i, 3): the
    options' ``bounds``, else Γ's box grown by their ``padding`` (``region_of_interest``). → (2, 3) float64."""
    if options.get("bounds") is not None:
        return np.asarray(options["bounds"], dtype=np.float64)
    return region_of_interest(loops, **({"padding": options["padding"]} if options.get("padding") is not None else {}))


def flux_sign(current, vertices: np.ndarray, faces: np.ndarray, chunk_size: int = 1 << 16) -> float:
    """The sign of the current's flux through a triangle mesh, Σ_faces (n · ω(centre)) · area: +1 when the
    faces' normals point along the current, −1 when against it (0 for no flux).
    vertices (V, 3), faces (F, 3)."""
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    centres = torch.as_tensor(np.array(mesh.triangles_center), dtype=torch.float32, device=device_of(current))
    _, omega = current.evaluate(centres, chunk_size)
    return float(np.sign((mesh.face_normals * omega.cpu().numpy()).sum(1) @ mesh.area_faces))


def _drop_small_components(verts: np.ndarray, faces: np.ndarray, min_fraction: float) -> np.ndarray:
    """Drops connected components with less than ``min_fraction`` of the total area (specks)."""
    if len(faces) == 0 or min_fraction <= 0:
        return faces
    mesh = trimesh.Trimesh(verts, faces, process=False)
    labels = trimesh.graph.connected_component_labels(mesh.face_adjacency, node_count=len(faces))
    areas = np.bincount(labels, weights=mesh.area_faces)
    return faces[(areas >= min_fraction * areas.sum())[labels]]


def _drop_closed_components(verts: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, float]:
    """Drops connected components without a border edge (closed surfaces: their boundary is empty, so they
    span no part of Γ). Called after the tube cut, where every sheet that reaches Γ has a border.
    → (the remaining faces, the area dropped)."""
    if len(faces) == 0:
        return faces, 0.0
    mesh = trimesh.Trimesh(verts, faces, process=False)
    labels = trimesh.graph.connected_component_labels(mesh.face_adjacency, node_count=len(faces))
    on_border = np.zeros(len(verts), dtype=bool)
    on_border[border_edges(faces).ravel()] = True
    bordered = np.zeros(labels.max() + 1, dtype=bool)
    bordered[labels[on_border[faces].any(1)]] = True  # a component with a face on a border edge's vertex
    dropped = float(mesh.area_faces[~bordered[labels]].sum())
    return faces[bordered[labels]], dropped


# Peak memory of meshing per grid node: the nodes in float64 and float32, the sampled volume, marching cubes'
# work arrays. Measured with `python -m deepcurrents.cli.extract` on the quick start's trefoil: 113-135 bytes a node
# at resolutions 256 and 384 (peak RSS less the process's own); the check uses a little less, so that it refuses
# only grids that cannot fit.
NODE_BYTES = 100
# the level set is meshed once more at 1.5× where Newton moved more than this share of the marched vertices by more
# than half a cell (extract_surface)
DRAGGED_SHARE = 0.01


def grid_shape(bounds: np.ndarray, resolution: int, key: str = "resolution") -> tuple[tuple[int, int, int], float]:
    """The shape of the meshing grid over ``bounds`` (2, 3) with ``resolution`` cells along its longest side, and
    its voxel size; one sentence naming ``key`` when its arrays (``NODE_BYTES`` a node) cannot fit in the memory
    available here (a resolution of 2048 asks for billions of nodes)."""
    extent = bounds[1] - bounds[0]
    voxel = float(extent.max()) / resolution
    shape = tuple(int(s) for s in np.maximum(2, np.ceil(extent / voxel).astype(int) + 1))
    require_memory(f"{key}={resolution}", NODE_BYTES * math.prod(shape),
                   f"a {shape[0]}×{shape[1]}×{shape[2]} meshing grid, ")
    return shape, voxel


def _grid(bounds: np.ndarray, resolution: int, key: str = "resolution"
          ) -> tuple[np.ndarray, tuple[int, int, int], float]:
    """Nodes (G0·G1·G2, 3) of a cubic grid from ``bounds[0]``, ``resolution`` cells along the longest side
    of ``bounds`` (2, 3) → (nodes, shape, voxel size); ``key`` names the resolution in a refusal."""
    shape, voxel = grid_shape(bounds, resolution, key)
    axes = [np.linspace(bounds[0, i], bounds[0, i] + voxel * (shape[i] - 1), shape[i]) for i in range(3)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3), shape, voxel


# (resolution key, resolution, cell width) already warned about: a family's interpolation meshes each step alike
_WIDENED_SAID: set[tuple[str, int, float]] = set()


@torch.no_grad()
@reads_level_sets
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
    strip_rows: int | None = None,
    level_blend: float = 0.0,
    chunk_size: int = 1 << 16,
    resolution_key: str = "resolution",
    refine_aliased: bool = True,
) -> MeshingResult:
    """The surface of a 3D current as a triangle mesh whose border lies on Γ (see the module docstring).

    Args:
        current: a NeuralCurrent-like module with ``f``, ``evaluate``, ``alpha``, ``alpha_scale``, ``loops``.
        resolution: grid cells along the longest side of ``bounds``.
        delta: keep faces with |ω| ≥ delta at their centroid (paper: 5e-3).
        boundary_tube: radius τ of the tube around Γ that is cut and closed by the strip (at least 1.5 voxels).
        bounds: (2, 3) region to mesh; default Γ's bounding box grown by ``padding``.
        min_component: drop components smaller than this fraction of the total area.
        min_alignment: level set only: keep faces where cos(ω, ∇f) is at least this (drops the
            complementary level surface, where ω points against ∇f).
        close_boundary: False: the |ω| ≥ δ cut only, no tube, no strip, no Newton (with method="level_set":
            the paper's mesh).
        method: a key of ``METHODS``. "phase" (default, ``meshing.phase``): every sheet of the surface,
            whatever f's offset there. "level_set" (``meshing.level_set``): the paper's f = s, one level for
            the whole surface (it misses sheets where f's jump does not straddle s, e.g. an undertrained
            trefoil).
        strip_rows: rows of triangles in each strip from the cut border to Γ. None: one row (triangles
            τ long) for the phase, so minimal-surface meshes are as they were; about τ/voxel rows (triangles
            about a voxel tall, no slivers) for every other method, the level set of reconstructions and
            families among them.
        resolution_key: the setting that gave ``resolution``, named if its grid cannot fit in memory
            (``evaluation.mesh.resolution`` for a run's final mesh; an app's ``resolution``).
        refine_aliased: phase method: where the current's jump is so thin that its phase turns by more than half
            a turn between two nodes away from Γ (``grid_angle.aliased_edges``), mesh once more at 1.5× the
            resolution (if that grid fits in memory), said in the log: marching cubes loses the sheet at such
            edges (a sharpened catenoid at 128³: holes, +19 % of area; at 192³ closed, +0.6 %). Grids without
            such edges (the trained trefoils of ``make run`` and of 300 vertices, at 128³) mesh as before. Level set:
            where Newton moves more than ``DRAGGED_SHARE`` of the marched vertices by more than half a cell (f's jump
            thinner than the grid, spikes: a 180-s hand reconstruction at 96³), the same.
    """
    if method not in METHODS:
        raise ValueError(f"method={method!r} must be one of {MESH_METHODS} (resolve 'auto' with mesh_method).")
    options = {"level_blend": level_blend} if method == "level_set" else {}
    finder = METHODS[method](current, chunk_size, **options)
    loops = [lp.detach().cpu().double().numpy() for lp in current.loops]
    bounds = mesh_region(loops, {"bounds": bounds, "padding": padding})
    nodes, shape, voxel = _grid(bounds, resolution, resolution_key)
    dev = device_of(current)
    closed_area = 0.0
    vol, level = finder.sample(torch.as_tensor(nodes, dtype=torch.float32, device=dev), shape, loops, voxel)
    tube = max(boundary_tube, 1.5 * voxel) if close_boundary else 0.0

    def finer_resolution(why: str) -> int | None:
        """1.5× the resolution, or None (said in a warning) where that grid does not fit in memory. ``why``: what
        this grid showed."""
        finer = math.ceil(1.5 * resolution)
        try:
            grid_shape(bounds, finer, resolution_key)  # the memory check only
        except ConfigError:
            log.warning("%s of the %s=%d grid, so its mesh may be wrong there; %s=%d does not fit in memory.",
                        why, resolution_key, resolution, resolution_key, finer)
            return None
        return finer

    def mesh_finer(finer: int, why: str, harm: str) -> MeshingResult:
        log.info("%s of the %s=%d grid, where marching cubes %s: meshed at %d instead.", why, resolution_key,
                 resolution, harm, finer)
        return extract_surface(current, finer, delta, boundary_tube, bounds, padding, newton_steps, min_component,
                               min_alignment, close_boundary, method, strip_rows, level_blend, chunk_size,
                               resolution_key, refine_aliased=False)

    aliased = getattr(finder, "aliased_points", None)
    if refine_aliased and aliased is not None and len(aliased):
        starts, ends, _ = closed_loop_segments(loops)  # next to Γ Ω/2 turns fast anyway, and the tube is cut
        count = int((segment_distance(aliased, starts, ends) > max(tube, boundary_tube) + 2.0 * voxel).sum())
        why = f"The current's phase turns by more than half a turn between nodes at {count} edges"
        if count and (finer := finer_resolution(why)) is not None:
            del vol, finder
            return mesh_finer(finer, why, "would lose the sheet (its jump only a few cells thick)")
    widened = tube > boundary_tube  # by the voxels: the border is cut and closed at this coarse a scale
    if widened and (resolution_key, resolution, round(voxel, 9)) not in _WIDENED_SAID:  # once, not per member
        _WIDENED_SAID.add((resolution_key, resolution, round(voxel, 9)))
        enough = (f"; {resolution_key}={math.ceil(resolution * 1.5 * voxel / boundary_tube)} or more keeps it as set"
                  if boundary_tube > 0 else "")
        log.warning("%s=%d gives %.3g-wide cells, so the boundary tube is widened from %.3g to %.3g (1.5 cells): a "
                    "mesh this coarse can misplace its border and add area%s.", resolution_key, resolution, voxel,
                    boundary_tube, tube, enough)
    empty = MeshingResult(trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), int)), finder.reported_level, 0)
    if not (vol.min() < level < vol.max()):
        log.warning("%s in the meshing region; the mesh is empty.", finder.empty_reason())
        return empty
    verts, faces, _, _ = marching_cubes(vol, level=level, spacing=(voxel,) * 3)
    faces = finder.keep_marched(verts / voxel, faces)
    # only the kept faces' vertices go on (the phase's marched set also holds φ ≈ θ off the surface: 60k
    # vertices of which 13k are kept on the make-run trefoil, and the tube cut measures each one's distance)
    used, faces = np.unique(faces, return_inverse=True)
    verts = verts[used].astype(np.float64) + bounds[0]
    faces = faces.reshape(-1, 3).astype(np.int64)
    if tube > 0:
        before = len(faces)
        verts, faces = cut_tube(verts, faces, loops, tube)
        if before and not len(faces):  # not the current's fault: say which setting removed the surface
            log.warning("The boundary tube (radius %.3g about Γ) holds the whole level set: the mesh is empty; %s.",
                        tube, f"raise {resolution_key} (the tube is 1.5 cells wide)" if widened
                        else "lower boundary_tube")
            return empty

    if len(faces):
        centroids = torch.as_tensor(verts[faces].mean(1), dtype=torch.float32, device=dev)
        _, omega = current.evaluate(centroids, chunk_size)
        keep = omega.norm(dim=-1) >= delta
        if tube > 0 and min_alignment > -1:
            keep &= finder.keep_carrying(centroids, omega, min_alignment)
        faces = _drop_small_components(verts, faces[keep.cpu().numpy()], min_component)
        if tube > 0:
            faces, closed_area = _drop_closed_components(verts, faces)
            if closed_area > 0:
                log.info("Dropped closed components of area %.4g (they span no part of Γ).", closed_area)
    if len(faces) == 0:
        log.warning("No part of the surface carries the current (|ω| ≥ %.3g); the mesh is empty.", delta)
        return empty
    used = np.unique(faces)
    remap = np.full(len(verts), -1)
    remap[used] = np.arange(len(used))
    verts, faces = verts[used], remap[faces]

    if tube > 0 and newton_steps > 0:
        marched, verts = verts, finder.newton(verts, voxel, newton_steps)
        # the level set's own aliasing check: where f's jump is thinner than a cell, the marched surface misses the
        # level set and Newton drags its vertices across cells, raising spikes (a 180-s hand reconstruction at 96³:
        # 11 % of its vertices moved more than half a cell, UCD 0.00178 and 1.07× the target's area; at 192³ none,
        # 0.00125 and 0.96×; every 1000-step part and minimal surface measured: none)
        if refine_aliased and method == "level_set":
            dragged = float((np.linalg.norm(verts - marched, axis=1) > 0.5 * voxel).mean())
            why = (f"Newton moved {100 * dragged:.0f} % of the marched vertices more than half a cell onto the level "
                   "set (f's jump thinner than the grid)")
            if dragged > DRAGGED_SHARE and (finer := finer_resolution(why)) is not None:
                del vol, finder, marched, verts, faces
                return mesh_finer(finer, why, "raises spikes")
    if flux_sign(current, verts, faces, chunk_size) < 0:
        faces = faces[:, ::-1].copy()
    zipped = 0
    if tube > 0:
        if strip_rows is None:
            strip_rows = 1 if method == "phase" else max(1, round(tube / voxel))
        verts, faces, zipped = close_onto_loops(verts, faces, loops, voxel, tube, strip_rows)
    mesh = trimesh.Trimesh(verts, faces, process=True)
    mesh.update_faces(mesh.nondegenerate_faces())
    mesh.remove_unreferenced_vertices()
    # Pinholes: a lone face inside the surface whose centroid fell under the |ω| or alignment test leaves a hole
    # of three edges, and boundary_error, the border's distance from Γ, reads it as a tear (0.74 on a hand
    # reconstruction, one face of 24106). trimesh fills holes of three and four edges, wound like their rims.
    trimesh.repair.fill_holes(mesh)
    if tube > 0:
        _say_open_border(mesh, loops, tube, voxel, bounds, method, resolution_key, resolution)
    return MeshingResult(mesh, finder.reported_level, zipped, closed_area)


def _say_open_border(mesh: trimesh.Trimesh, loops: list[np.ndarray], tube: float, voxel: float, bounds: np.ndarray,
                     method: str, resolution_key: str, resolution: int) -> None:
    """A warning when a mesh whose border was closed onto Γ still has border edges farther than the tube and two
    cells from Γ. On the faces of the meshed box ``bounds``: the box cuts the surface (a family member in the
    family's cube), so widen it. Elsewhere: a hole or a tear. With the phase, where the current's jump is only a
    few cells thick its phase can turn by more than half a turn between two nodes, and e^{iφ} sampled there turns
    the other way: marching cubes puts the crossing on the off-surface side and the side test drops it (a sharpened
    catenoid at 128³: the phase's 10–90 % rise 1.8–2.2 cells wide at the holes, +19 % of area, border 0.15 off Γ;
    at 192³ closed, +0.6 %; ``extract_surface``'s ``refine_aliased`` now meshes such grids finer by itself). A
    surface that Γ pierces (the Borromean rings) leaves a slit at any resolution."""
    edges = mesh.edges[trimesh.grouping.group_rows(mesh.edges_sorted, require_count=1)]
    if not len(edges):
        return
    middle = np.asarray(mesh.vertices)[edges].mean(1)
    starts, ends, _ = closed_loop_segments(loops)
    distance = segment_distance(middle, starts, ends)
    far = distance > tube + 2.0 * voxel
    if not far.any():
        return
    on_box = ((np.abs(middle - bounds[0]) < voxel) | (np.abs(middle - bounds[1]) < voxel)).any(1)
    if (far & on_box).any():
        log.warning("The meshed box cuts the surface: %d border edges lie on its faces, up to %.3g from Γ; widen it "
                    "(evaluation.mesh.padding, or an app's padding=).", int((far & on_box).sum()),
                    distance[far & on_box].max())
    inside = far & ~on_box
    if inside.any():
        why = (f" Where the current's jump is only a few of the {voxel:.3g}-wide cells thick the grid cannot follow "
               f"its phase: mesh it finer ({resolution_key}={math.ceil(1.5 * resolution)} or more; a surface that "
               "Γ pierces keeps such a slit at any resolution)." if method == "phase" else "")
        log.warning("The mesh has a border up to %.3g from Γ (%d of its %d border edges farther than the tube and two "
                    "cells, inside the meshed box): a hole or a tear.%s", distance[inside].max(), int(inside.sum()),
                    len(edges), why)
