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
from dataclasses import dataclass, replace

import igl
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
from deepcurrents.geometry.polyline import closed_loop_segments, loop_gaps, segment_distance
from deepcurrents.geometry.topology import border_edges, face_components

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
    """``options`` (``evaluation.mesh``, less its ``polish``) as ``extract_surface``'s arguments, ``method`` "auto"
    (or unset) replaced by the model kind's ``default``: "phase" for
    minimal currents (ω ≈ 0 off the surface, so the phase is constant there), "level_set" for currents
    trained under a reconstruction metric (ω along the target's normal is free off the surface, which
    can turn the phase over twice: doubled sheets)."""
    options = {k: v for k, v in dict(options).items() if k != "polish"}  # the mesh flow after it (meshing.polish)
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


def _drop_closed_components(verts: np.ndarray, faces: np.ndarray, near: tuple[np.ndarray, np.ndarray] | None = None,
                            within: float = 0.0) -> tuple[np.ndarray, float]:
    """Drops connected components without a border edge (closed surfaces: their boundary is empty, so they
    span no part of Γ). Called after the tube cut, where every sheet that reaches Γ has a border. ``near``: a
    target (vertices, faces); a closed component whose vertices lie within ``within`` of it (median) is kept: a
    cavity of the target (a mouth, an eye socket) that the level set pinched off where its opening is thinner
    than the grid, not a bubble. → (the remaining faces, the area dropped)."""
    if len(faces) == 0:
        return faces, 0.0
    mesh = trimesh.Trimesh(verts, faces, process=False)
    labels = trimesh.graph.connected_component_labels(mesh.face_adjacency, node_count=len(faces))
    on_border = np.zeros(len(verts), dtype=bool)
    on_border[border_edges(faces).ravel()] = True
    bordered = np.zeros(labels.max() + 1, dtype=bool)
    bordered[labels[on_border[faces].any(1)]] = True  # a component with a face on a border edge's vertex
    if near is not None and not bordered.all():
        d2, _, _ = igl.point_mesh_squared_distance(np.ascontiguousarray(verts), np.ascontiguousarray(near[0]),
                                                   np.ascontiguousarray(near[1], dtype=np.int64))
        face_distance = np.sqrt(d2)[faces].mean(1)
        for label in np.flatnonzero(~bordered):
            bordered[label] = np.median(face_distance[labels == label]) <= within
    dropped = float(mesh.area_faces[~bordered[labels]].sum())
    return faces[bordered[labels]], dropped


# Peak memory of meshing per grid node (nodes, sampled volume, marching cubes' work arrays), a little under the
# measured (docs/notes/meshing.md), so that the check refuses only grids that cannot fit.
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


@dataclass(frozen=True)
class MeshSettings:
    """How ``extract_surface`` meshes (its arguments, documented there), for one grid."""

    resolution: int = 128
    delta: float = 5e-3
    boundary_tube: float = 0.04
    newton_steps: int = 3
    min_component: float = 0.01
    min_alignment: float = 0.5
    close_boundary: bool = True
    method: str = "phase"
    strip_rows: int | None = None
    chunk_size: int = 1 << 16
    resolution_key: str = "resolution"
    closed_on: tuple[np.ndarray, np.ndarray] | None = None
    weak_share: float = 0.0


@dataclass
class _Refine:
    """A grid too coarse for the current: why (what it showed) and what marching cubes would do there."""

    why: str
    harm: str
    resolution: int


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
    said: set | None = None,
    closed_on: tuple[np.ndarray, np.ndarray] | None = None,
    weak_share: float = 0.0,
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
            the whole surface (it misses sheets where f's jump does not straddle s).
        strip_rows: rows of triangles in each strip from the cut border to Γ. None: one row (triangles
            τ long) for the phase; about τ/voxel rows (triangles about a voxel tall, no slivers) for every
            other method.
        resolution_key: the setting that gave ``resolution``, named if its grid cannot fit in memory
            (``evaluation.mesh.resolution`` for a run's final mesh; an app's ``resolution``).
        refine_aliased: mesh once more at 1.5× the resolution (if that grid fits in memory, said in the log) where
            the grid is too coarse for the current: phase, where the current's jump is so thin that its phase
            turns by more than half a turn between two nodes away from Γ (``grid_angle.aliased_edges``; marching
            cubes loses the sheet there); level set, where Newton moves more than ``DRAGGED_SHARE`` of the marched
            vertices by more than half a cell (f's jump thinner than the grid: spikes).
        said: the coarse-grid warnings already given in this chain of meshings (a family meshes many members on
            one grid): each is given once per set; None: always.
        closed_on: a reconstruction's target (vertices (V, 3), faces (F, 3)): closed pieces of the mesh that lie on
            it (median within two voxels) are kept, where others are dropped as bubbles (a cavity of the target
            whose opening the grid cannot resolve comes out closed).
        weak_share: > 0 (beyond the paper): regions whose |ω| is under this share of the median face's and that
            reach the tube around Γ are dropped (``_drop_weak_caps``: caps across Γ's openings); 0: off.
    """
    if method not in METHODS:
        raise ValueError(f"method={method!r} must be one of {MESH_METHODS} (resolve 'auto' with mesh_method).")
    settings = MeshSettings(resolution, delta, boundary_tube, newton_steps, min_component, min_alignment,
                            close_boundary, method, strip_rows, chunk_size, resolution_key, closed_on, weak_share)
    options = {"level_blend": level_blend} if method == "level_set" else {}
    loops = [lp.detach().cpu().double().numpy() for lp in current.loops]
    bounds = mesh_region(loops, {"bounds": bounds, "padding": padding})
    outcome = _mesh_once(current, METHODS[method](current, chunk_size, **options), loops, bounds, settings,
                         refine_aliased, said)
    if isinstance(outcome, _Refine):  # once: the finer grid is meshed as it comes
        log.info("%s of the %s=%d grid, where marching cubes %s: meshed at %d instead.", outcome.why,
                 resolution_key, resolution, outcome.harm, outcome.resolution)
        settings = replace(settings, resolution=outcome.resolution)
        outcome = _mesh_once(current, METHODS[method](current, chunk_size, **options), loops, bounds, settings,
                             False, said)
    return outcome


def _finer_resolution(bounds: np.ndarray, settings: MeshSettings) -> int | None:
    """1.5× the resolution, or None where that grid does not fit in memory."""
    finer = math.ceil(1.5 * settings.resolution)
    try:
        grid_shape(bounds, finer, settings.resolution_key)  # the memory check only
    except ConfigError:
        return None
    return finer


def _refine_or_say(why: str, harm: str, bounds: np.ndarray, settings: MeshSettings) -> _Refine | None:
    """A request to mesh finer where the grid is too coarse (``why``) and a finer one fits; else None, with a
    warning that the finer grid does not fit in memory."""
    finer = _finer_resolution(bounds, settings)
    if finer is None:
        log.warning("%s of the %s=%d grid, so its mesh may be wrong there; %s=%d does not fit in memory.", why,
                    settings.resolution_key, settings.resolution, settings.resolution_key,
                    math.ceil(1.5 * settings.resolution))
        return None
    return _Refine(why, harm, finer)


def _say_widened_tube(settings: MeshSettings, voxel: float, tube: float, said: set | None) -> None:
    """A warning that the grid's cells widened the boundary tube (once per ``said`` set and grid)."""
    key = ("widened", settings.resolution_key, settings.resolution, round(voxel, 9))
    if said is not None:
        if key in said:
            return
        said.add(key)
    resolution, name, boundary_tube = settings.resolution, settings.resolution_key, settings.boundary_tube
    enough = (f"; {name}={math.ceil(resolution * 1.5 * voxel / boundary_tube)} or more keeps it as set"
              if boundary_tube > 0 else "")
    log.warning("%s=%d gives %.3g-wide cells, so the boundary tube is widened from %.3g to %.3g (1.5 cells): a "
                "mesh this coarse can misplace its border and add area%s.", name, resolution, voxel,
                boundary_tube, tube, enough)


# The tube around Γ is at most this share of the smallest gap between two loops of Γ: wider, the cut around two close
# loops (a torso's hips, 3–5 % of its box apart) joins their holes into one, and each loop's strip then fans across it.
LOOP_GAP_SHARE = 0.4


def _tube_radii(s: MeshSettings, voxel: float, gaps: np.ndarray, said: set | None) -> np.ndarray:
    """τ_i for each loop of Γ: ``boundary_tube``, at least 1.5 voxels, and at most ``LOOP_GAP_SHARE`` of the gap from
    loop i to its nearest other loop, even where that is under 1.5 voxels (said once: such a grid, which could not be
    refined enough, places those loops' borders less well; joined holes would be worse), but not under half a voxel:
    loops that touch at the grid's scale (or truly touch) keep the whole tube, said once too. Loops far from the
    others keep the whole tube. gaps (L,) → (L,)."""
    tube = max(s.boundary_tube, 1.5 * voxel)
    narrowed = LOOP_GAP_SHARE * np.asarray(gaps, np.float64)
    tubes = np.minimum(tube, narrowed)
    touching = narrowed < 0.5 * voxel
    tubes[touching] = tube
    gap = float(np.min(gaps)) if len(gaps) else np.inf
    if touching.any():
        why = f"Two loops of Γ come within {gap:.3g}, under a cell of the {s.resolution_key}={s.resolution} grid: " \
              "the boundary tube cannot keep their holes apart there"
    elif (tubes < 1.5 * voxel).any():
        why = (f"Two loops of Γ are {gap:.3g} apart, so their boundary tube is {tubes.min():.3g}, under 1.5 cells of "
               f"the {s.resolution_key}={s.resolution} grid, to keep their holes apart; a finer {s.resolution_key} "
               "places their borders better")
    else:
        return tubes
    if said is None or "gap" not in said:
        log.warning("%s.", why)
        if said is not None:
            said.add("gap")
    return tubes


def _resolution_for_gap(bounds: np.ndarray, s: MeshSettings, voxel: float, gap: float) -> int | None:
    """The resolution whose cells make 1.5 of them fit in ``LOOP_GAP_SHARE`` of the loops' gap, where this grid's do
    not, at most twice this one (as fine as that where more is needed) and fitting in memory; else None."""
    if 1.5 * voxel <= LOOP_GAP_SHARE * gap or not np.isfinite(gap) or LOOP_GAP_SHARE * gap < 0.25 * voxel:
        return None  # apart already, or touching even on a grid twice as fine (they keep the whole tube)
    finer = min(2 * s.resolution, math.ceil(s.resolution * 1.5 * voxel / (LOOP_GAP_SHARE * gap)))
    try:
        grid_shape(bounds, finer, s.resolution_key)  # the memory check only
    except ConfigError:
        return None
    return finer


def _mesh_once(current, finder: MeshMethod, loops: list[np.ndarray], bounds: np.ndarray, settings: MeshSettings,
               refine: bool, said: set | None) -> MeshingResult | _Refine:
    """Meshes the current once on the grid of ``settings`` over ``bounds`` (steps 1–6 of the module docstring), or,
    with ``refine``, asks for a finer grid (``_Refine``) where this one is too coarse and a finer one fits."""
    s = settings
    nodes, shape, voxel = _grid(bounds, s.resolution, s.resolution_key)
    gaps = loop_gaps(loops) if s.close_boundary else np.full(len(loops), np.inf)
    gap = float(gaps.min()) if len(gaps) else np.inf
    if refine and (finer := _resolution_for_gap(bounds, s, voxel, gap)) is not None:
        return _Refine(f"Two loops of Γ are {gap:.3g} apart, under 3.75 cells",
                       "would leave their holes joined by the tube", finer)
    dev = device_of(current)
    vol, level = finder.sample(torch.as_tensor(nodes, dtype=torch.float32, device=dev), shape, loops, voxel)
    tubes = _tube_radii(s, voxel, gaps, said) if s.close_boundary else np.zeros(len(loops))
    tube = float(tubes.max()) if len(tubes) else 0.0  # the widest, for the checks that need one radius
    aliased = getattr(finder, "aliased_points", None)
    if refine and aliased is not None and len(aliased):
        starts, ends, _ = closed_loop_segments(loops)  # next to Γ Ω/2 turns fast anyway, and the tube is cut
        count = int((segment_distance(aliased, starts, ends) > max(tube, s.boundary_tube) + 2.0 * voxel).sum())
        why = f"The current's phase turns by more than half a turn between nodes at {count} edges"
        if count and (finer := _refine_or_say(why, "would lose the sheet (its jump only a few cells thick)", bounds,
                                              s)):
            return finer
    widened = tube > s.boundary_tube  # by the voxels: the border is cut and closed at this coarse a scale
    if widened:
        _say_widened_tube(s, voxel, tube, said)
    empty = MeshingResult(trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), int)), finder.reported_level, 0)
    if not (vol.min() < level < vol.max()):
        log.warning("%s in the meshing region; the mesh is empty.", finder.empty_reason())
        return empty
    verts, faces, _, _ = marching_cubes(vol, level=level, spacing=(voxel,) * 3)
    del vol
    faces = finder.keep_marched(verts / voxel, faces)
    # only the kept faces' vertices go on (the phase's marched set also holds φ ≈ θ off the surface)
    used, faces = np.unique(faces, return_inverse=True)
    verts = verts[used].astype(np.float64) + bounds[0]
    faces = faces.reshape(-1, 3).astype(np.int64)
    if tube > 0:
        before = len(faces)
        verts, faces = cut_tube(verts, faces, loops, tubes)
        if before and not len(faces):  # not the current's fault: say which setting removed the surface
            log.warning("The boundary tube (radius %.3g about Γ) holds the whole level set: the mesh is empty; %s.",
                        tube, f"raise {s.resolution_key} (the tube is 1.5 cells wide)" if widened
                        else "lower boundary_tube")
            return empty
    verts, faces, closed_area = _faces_carrying_the_current(current, finder, verts, faces, loops, tubes, s, voxel)
    if len(faces) == 0:
        log.warning("No part of the surface carries the current (|ω| ≥ %.3g); the mesh is empty.", s.delta)
        return empty
    if tube > 0 and s.newton_steps > 0:
        marched, verts = verts, finder.newton(verts, voxel, s.newton_steps)
        if refine and s.method == "level_set":  # the level set's own aliasing check
            dragged = float((np.linalg.norm(verts - marched, axis=1) > 0.5 * voxel).mean())
            why = (f"Newton moved {100 * dragged:.0f} % of the marched vertices more than half a cell onto the level "
                   "set (f's jump thinner than the grid)")
            if dragged > DRAGGED_SHARE and (finer := _refine_or_say(why, "raises spikes", bounds, s)):
                return finer
    if flux_sign(current, verts, faces, s.chunk_size) < 0:
        faces = faces[:, ::-1].copy()
    zipped = 0
    if tube > 0:
        rows = (s.strip_rows if s.strip_rows is not None else 1 if s.method == "phase"
                else np.maximum(1, np.round(tubes / voxel)).astype(np.int64))
        verts, faces, zipped = close_onto_loops(verts, faces, loops, voxel, tubes, rows)
    mesh = trimesh.Trimesh(verts, faces, process=True)
    mesh.update_faces(mesh.nondegenerate_faces())
    mesh.remove_unreferenced_vertices()
    # Pinholes: a lone face inside the surface whose centroid fell under the |ω| or alignment test leaves a hole
    # of three edges, which boundary_error would read as a tear; trimesh fills holes of three and four edges.
    trimesh.repair.fill_holes(mesh)
    if tube > 0:
        _say_open_border(mesh, loops, tube, voxel, bounds, s.method, s.resolution_key, s.resolution)
    return MeshingResult(mesh, finder.reported_level, zipped, closed_area)


def _drop_weak_caps(verts: np.ndarray, faces: np.ndarray, strength: np.ndarray, loops: list[np.ndarray],
                    tubes: np.ndarray, voxel: float, share: float) -> np.ndarray:
    """The faces without the caps across Γ's openings: connected regions of faces whose |ω| is under ``share`` of
    the median |ω| of the mesh's faces and that reach the cut tube around Γ. A level set of f spans each opening
    of Γ with a cap where f does not cancel α there exactly (two close loops: a torso's hips), and such a cap carries
    a fraction of the sheet's current; weak regions inside the surface (a thin fingertip) are kept, as holes there
    would tear it. verts (V, 3), faces (F, 3), strength (F,) → faces (F', 3)."""
    weak = strength < share * np.median(strength) if len(faces) else np.zeros(0, bool)
    if not weak.any():
        return faces
    weak_faces = faces[weak]
    label = face_components(weak_faces, len(verts))
    reach = np.zeros(len(verts), bool)
    for loop, t in zip(loops, tubes, strict=True):
        starts, ends, _ = closed_loop_segments([loop])
        reach |= segment_distance(verts, starts, ends) < t + 1.5 * voxel
    at_tube = np.zeros(label.max() + 1, bool)
    np.logical_or.at(at_tube, np.repeat(label, 3), reach[weak_faces.reshape(-1)])
    drop = np.zeros(len(faces), bool)
    drop[np.flatnonzero(weak)[at_tube[label]]] = True
    if drop.any():
        log.info("Dropped %d weak faces (|ω| under %.2g of the median) that reach Γ's tube: caps across its openings.",
                 int(drop.sum()), share)
    return faces[~drop]


def _faces_carrying_the_current(current, finder: MeshMethod, verts: np.ndarray, faces: np.ndarray,
                                loops: list[np.ndarray], tubes: np.ndarray, s: MeshSettings, voxel: float
                                ) -> tuple[np.ndarray, np.ndarray, float]:
    """Step 3 of the module docstring: the faces whose centroid has |ω| ≥ δ (and, with a tube, that the method
    says carry the current), without specks and, with a tube (``tubes`` (L,), each loop's; zeros: none), without
    closed bubbles or weak caps; unused vertices dropped. → (vertices, faces, the closed bubbles' area)."""
    tube = float(tubes.max()) if len(tubes) else 0.0
    closed_area = 0.0
    if len(faces):
        centroids = torch.as_tensor(verts[faces].mean(1), dtype=torch.float32, device=device_of(current))
        _, omega = current.evaluate(centroids, s.chunk_size)
        strength = omega.norm(dim=-1)
        keep = strength >= s.delta
        if tube > 0 and s.min_alignment > -1:
            keep &= finder.keep_carrying(centroids, omega, s.min_alignment)
        keep = keep.cpu().numpy()
        faces = faces[keep]
        if tube > 0 and s.weak_share > 0:
            faces = _drop_weak_caps(verts, faces, strength.cpu().numpy()[keep], loops, tubes, voxel, s.weak_share)
        faces = _drop_small_components(verts, faces, s.min_component)
        if tube > 0:
            faces, closed_area = _drop_closed_components(verts, faces, s.closed_on, 2.0 * voxel)
            if closed_area > 0:
                log.info("Dropped closed components of area %.4g (they span no part of Γ).", closed_area)
    if len(faces) == 0:
        return verts, faces, closed_area
    used = np.unique(faces)
    remap = np.full(len(verts), -1)
    remap[used] = np.arange(len(used))
    return verts[used], remap[faces], closed_area


def _say_open_border(mesh: trimesh.Trimesh, loops: list[np.ndarray], tube: float, voxel: float, bounds: np.ndarray,
                     method: str, resolution_key: str, resolution: int) -> None:
    """A warning when a mesh whose border was closed onto Γ still has border edges farther than the tube and two
    cells from Γ. On the faces of the meshed box ``bounds``: the box cuts the surface (a family member in the
    family's cube), so widen it. Elsewhere: a hole or a tear. With the phase, where the current's jump is only a
    few cells thick its phase can turn by more than half a turn between two nodes, and e^{iφ} sampled there turns
    the other way: marching cubes puts the crossing on the off-surface side and the side test drops it
    (``refine_aliased`` meshes such grids finer by itself). A surface that Γ pierces (the Borromean rings) leaves a
    slit at any resolution."""
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
