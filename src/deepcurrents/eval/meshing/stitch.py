"""Stitching the meshes of parts along the boundary curves they share (paper §6: "stitching together DeepCurrents
along their boundaries"): one mesh whose seams are the shared loops themselves.

Each part's mesh ends on its Γ (``border.close_onto_loops`` zips it onto the loop, densified to the part's own voxel),
so the two sides of a shared loop have their border vertices on the same polyline, at different places along it.
The seam is made of the loop's vertices and every border vertex of either side, each placed once on the polyline by
its (segment, fraction) and shared: a border edge of one side that passes over seam vertices of the other is split
there (its triangle becomes a fan to its third vertex). The two sides then use identical seam vertices, and where
every loop has its two sides, the stitched mesh has no border. A part whose faces point against its target's
normals is flipped first, so that the stitched surface is consistently oriented.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import igl
import numpy as np
import trimesh

from deepcurrents.geometry.polyline import closest_on_segments
from deepcurrents.geometry.topology import SurfaceTopology, border_loops, surface_topology

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SharedLoop:
    """A closed polyline (M, 3) that two parts share as a border, and their names."""

    name: str
    parts: tuple[str, str]
    vertices: np.ndarray


@dataclass
class StitchedMesh:
    """The stitched mesh, which part each face came from, each loop's seam vertices (indices into the mesh, in the
    loop's order), the loops left open (a side with no border along it) with why, and the topology."""

    mesh: trimesh.Trimesh
    face_part: np.ndarray
    part_names: list[str]
    seams: dict[str, np.ndarray]
    open_loops: dict[str, str] = field(default_factory=dict)
    topology: SurfaceTopology | None = None
    flipped: list[str] = field(default_factory=list)

    @property
    def border_edges(self) -> int:
        """The number of edges with one face (0 for a closed stitched body)."""
        from deepcurrents.geometry.topology import border_edges

        return int(len(border_edges(np.asarray(self.mesh.faces))))


def loop_parameter(points: np.ndarray, loop: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where points lie along a closed polyline: (parameter in [0, M): segment index + fraction along it, distance).
    points (N, 3), loop (M, 3)."""
    ends = np.roll(loop, -1, 0)
    dist, closest, seg = closest_on_segments(points, loop, ends)
    d = ends[seg] - loop[seg]
    t = np.clip(((closest - loop[seg]) * d).sum(1) / np.maximum((d * d).sum(1), 1e-300), 0.0, 1.0)
    return (seg + t) % len(loop), dist


def _point_at(loop: np.ndarray, par: np.ndarray) -> np.ndarray:
    """Points at parameters ``par`` (N,) of a closed polyline (M, 3), each computed once from its segment."""
    seg = np.floor(par).astype(np.int64) % len(loop)
    t = (par - np.floor(par))[:, None]
    return loop[seg] + t * (np.roll(loop, -1, 0)[seg] - loop[seg])


def orient_to_target(mesh: trimesh.Trimesh, target: trimesh.Trimesh) -> tuple[trimesh.Trimesh, bool]:
    """The mesh with its faces flipped if their normals point against the target's at the closest points (area
    weighted). → (mesh, whether it was flipped)."""
    if len(mesh.faces) == 0:
        return mesh, False
    _, face, _ = igl.point_mesh_squared_distance(np.ascontiguousarray(mesh.triangles_center, np.float64),
                                                 np.ascontiguousarray(target.vertices, np.float64),
                                                 np.ascontiguousarray(target.faces, np.int64))
    agreement = float((mesh.area_faces * (mesh.face_normals * target.face_normals[face]).sum(1)).sum())
    if agreement >= 0:
        return mesh, False
    return trimesh.Trimesh(mesh.vertices, np.asarray(mesh.faces)[:, ::-1], process=False), True


def _border_along(vertices: np.ndarray, faces: np.ndarray, loop: np.ndarray, tolerance: float
                  ) -> tuple[np.ndarray, np.ndarray] | None:
    """The border loop of a mesh that lies on a closed polyline (every vertex within ``tolerance``) and goes once
    around it: (its vertex indices, their parameters), or None."""
    for border in border_loops(faces):
        par, dist = loop_parameter(vertices[border], loop)
        if dist.max() > tolerance:
            continue
        steps = (np.diff(np.append(par, par[0])) + len(loop) / 2) % len(loop) - len(loop) / 2
        if abs(abs(steps.sum()) - len(loop)) < 0.5 and (np.sign(steps) == np.sign(steps.sum())).all():
            return border, par
    return None


def stitch_parts(parts: Mapping[str, trimesh.Trimesh], loops: Sequence[SharedLoop], tolerance: float = 1e-6,
                 targets: Mapping[str, trimesh.Trimesh] | None = None, merge: float = 1e-9) -> StitchedMesh:
    """One mesh from the parts' meshes joined along the shared loops (module docstring).

    parts: {name: mesh} in one frame; loops: the shared loops in that frame; tolerance: how far from a loop (in the
    mesh's units) a border vertex may lie to be on it; targets: {name: the part's target}, to orient each part's
    faces with its target's normals; merge: parameters closer than this (in segments) are one seam vertex."""
    names = list(parts)
    meshes = {}
    flipped = []
    for name in names:
        mesh = parts[name]
        if targets is not None and name in targets:
            mesh, was = orient_to_target(mesh, targets[name])
            if was:
                flipped.append(name)
        meshes[name] = (np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64))
    # every seam: its parameters (the loop's vertices and both sides' border vertices), merged
    seam_params: dict[str, np.ndarray] = {}
    sides: dict[tuple[str, str], tuple[np.ndarray, np.ndarray]] = {}  # (loop, part) → (border, parameters)
    open_loops: dict[str, str] = {}
    for loop in loops:
        params = [np.arange(len(loop.vertices), dtype=np.float64)]
        found = []
        for part in loop.parts:
            if part not in meshes:
                open_loops[loop.name] = f"part {part} has no mesh"
                continue
            along = _border_along(*meshes[part], loop.vertices, tolerance)
            if along is None:
                open_loops[loop.name] = f"the mesh of {part} has no border along it"
                continue
            sides[(loop.name, part)] = along
            found.append(part)
            params.append(along[1])
        if len(found) < 2:
            for part in found:  # a one-sided loop stays the part's own border
                sides.pop((loop.name, part))
            continue
        par = np.sort(np.concatenate(params))
        gaps = np.diff(np.append(par, par[0] + len(loop.vertices)))
        seam_params[loop.name] = par[gaps > merge]
    # the stitched mesh: seam vertices first, then each part's vertices off the seams
    all_vertices, seams, offset = [], {}, 0
    for loop in loops:
        if loop.name in seam_params:
            par = seam_params[loop.name]
            all_vertices.append(_point_at(loop.vertices, par))
            seams[loop.name] = offset + np.arange(len(par))
            offset += len(par)
    loop_by_name = {lp.name: lp for lp in loops}
    all_faces, face_part = [], []
    for j, name in enumerate(names):
        verts, faces = meshes[name]
        index = np.full(len(verts), -1, dtype=np.int64)
        inserts: dict[tuple[int, int], list[int]] = {}  # border edge (a, b) of the part → seam vertices between
        for (loop_name, part), (border, par) in sides.items():
            if part != name or loop_name not in seam_params:
                continue
            seam_par, m = seam_params[loop_name], len(loop_by_name[loop_name].vertices)
            nearest = np.argmin(np.abs((seam_par[None, :] - par[:, None] + m / 2) % m - m / 2), axis=1)
            index[border] = seams[loop_name][nearest]
            forward = ((np.roll(par, -1) - par) % m) < m / 2
            for k, (a, b) in enumerate(zip(border, np.roll(border, -1), strict=True)):
                i, i_next = nearest[k], nearest[(k + 1) % len(border)]
                n_seam = len(seam_par)
                step = 1 if forward[k] else -1
                between, q = [], (i + step) % n_seam
                while q != i_next:
                    between.append(int(seams[loop_name][q]))
                    q = (q + step) % n_seam
                if between:
                    inserts[(int(a), int(b))] = between
        off = index < 0
        index[off] = offset + np.arange(off.sum())
        offset += int(off.sum())
        all_vertices.append(verts[off])
        # faces off the seams are only renumbered; those on a border edge that passes over seam vertices are split
        on_seam = np.isin(faces, np.unique([a for a, _ in inserts])).any(1) if inserts else np.zeros(len(faces), bool)
        new_faces = [tuple(f) for f in index[faces[~on_seam]]]
        for tri in faces[on_seam]:
            chains = [inserts.get((int(tri[e]), int(tri[(e + 1) % 3])), []) for e in range(3)]
            split = [e for e in range(3) if chains[e]]
            if not split:
                new_faces.append(tuple(index[tri]))
            elif len(split) == 1:  # a fan from the corner opposite the split edge
                e = split[0]
                a, b, c = tri[e], tri[(e + 1) % 3], tri[(e + 2) % 3]
                chain = [index[a], *chains[e], index[b]]
                new_faces += [(chain[k], chain[k + 1], index[c]) for k in range(len(chain) - 1)]
            else:  # several split edges (a corner of a zipper): a fan from the triangle's centroid
                ring = [v for e in range(3) for v in (index[tri[e]], *chains[e])]
                centre = offset
                all_vertices.append(verts[tri].mean(0, keepdims=True))
                offset += 1
                new_faces += [(ring[k], ring[(k + 1) % len(ring)], centre) for k in range(len(ring))]
        all_faces.append(np.asarray(new_faces, dtype=np.int64).reshape(-1, 3))
        face_part.append(np.full(len(all_faces[-1]), j))
    vertices = np.concatenate(all_vertices) if all_vertices else np.zeros((0, 3))
    faces = np.concatenate(all_faces) if all_faces else np.zeros((0, 3), np.int64)
    face_part_arr = np.concatenate(face_part) if face_part else np.zeros(0, np.int64)
    keep = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 2] != faces[:, 0])
    mesh = trimesh.Trimesh(vertices, faces[keep], process=False)
    for name, why in open_loops.items():
        log.warning("Shared loop %s left open: %s.", name, why)
    return StitchedMesh(mesh, face_part_arr[keep], names, seams, open_loops, surface_topology(faces[keep]), flipped)
