"""Triangle-mesh files: one reader with the checks every caller needs (exists, readable, has triangles,
finite coordinates), and one writer that keeps the coordinates as computed. Callers add what is particular to
them (a reconstruction target must have a boundary, a family mesh must match the family's topology)."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import plyfile
import trimesh

from deepcurrents.errors import UserInputError
from deepcurrents.geometry.topology import first_copies

log = logging.getLogger(__name__)


def read_mesh(path: str | Path, what: str = "Mesh file", error: type[UserInputError] = UserInputError
              ) -> trimesh.Trimesh:
    """The triangle mesh in ``path`` (any format trimesh reads, vertices in the file's order, unprocessed).

    ``what`` names the input in the one-sentence error (``"target"`` → ``target='x.ply' does not exist.``;
    a phrase such as ``"Mesh file"`` → ``Mesh file 'x.ply' does not exist.``); ``error`` is the
    UserInputError subclass raised.
    """
    name = f"{what}='{path}'" if what.isidentifier() else f"{what} '{path}'"
    p = Path(str(path)).expanduser()
    if not p.is_file():
        raise error(f"{name} does not exist or is not a file.")
    try:
        mesh = trimesh.load(p, force="mesh", process=False)
    except Exception as err:  # trimesh raises many kinds for unreadable files
        raise error(f"{name} could not be read as a triangle mesh ({type(err).__name__}: {err}).") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise error(f"{name} holds no triangles.")
    if not np.isfinite(np.asarray(mesh.vertices)).all():
        raise error(f"{name} has NaN or infinite vertex coordinates.")
    vertices, faces = merge_coincident_vertices(np.asarray(mesh.vertices), np.asarray(mesh.faces), name)
    if len(vertices) < len(mesh.vertices):
        mesh = trimesh.Trimesh(vertices, faces, process=False)
    return mesh


def write_mesh(mesh: trimesh.Trimesh | trimesh.PointCloud, path: str | Path) -> None:
    """``mesh`` (or a point cloud) to ``path`` in the format its suffix names. A ``.ply`` keeps the vertices in
    float64 (binary PLY ``double``, by ``plyfile``): trimesh writes PLY vertices as float32, which moved a mesh
    about a curve at UTM-sized coordinates (5.4e6) by up to 0.5 units off its curve. Other formats are trimesh's
    (``.obj`` and ``.off`` as text at full precision; ``.stl`` and ``.glb`` are float32 by their specifications)."""
    path = Path(path)
    if path.suffix.lower() != ".ply":
        mesh.export(path)
        return
    v = np.asarray(mesh.vertices, dtype=np.float64)
    vertex = np.empty(len(v), dtype=[("x", "<f8"), ("y", "<f8"), ("z", "<f8")])
    vertex["x"], vertex["y"], vertex["z"] = v.T
    elements = [plyfile.PlyElement.describe(vertex, "vertex")]
    faces = np.asarray(getattr(mesh, "faces", np.zeros((0, 3))), dtype=np.int32)
    if len(faces) or isinstance(mesh, trimesh.Trimesh):
        face = np.empty(len(faces), dtype=[("vertex_indices", "<i4", (3,))])
        face["vertex_indices"] = faces
        elements.append(plyfile.PlyElement.describe(face, "face", len_types={"vertex_indices": "u1"}))
    plyfile.PlyData(elements, byte_order="<", comments=["DeepCurrents"]).write(str(path))


def merge_coincident_vertices(vertices: np.ndarray, faces: np.ndarray, name: str) -> tuple[np.ndarray, np.ndarray]:
    """One vertex per position: STL files store every triangle's corners apart, and exporters split vertices along
    UV and normal seams, which would make each triangle its own component or cut a slit into Γ along the seam.
    Vertices at exactly the same coordinates are merged into the first of them, with a warning naming ``name``;
    the kept vertices stay in the file's order, so a mesh without such copies comes back unchanged.
    (V, 3), (F, 3) → (V', 3), (F, 3)."""
    first = first_copies(vertices)
    kept = first == np.arange(len(vertices))
    if kept.all():
        return vertices, faces
    rank = np.cumsum(kept) - 1  # new index of each kept vertex, in the file's order
    log.warning("%s: merged %d vertices that repeat another vertex's position (as STL files and texture seams "
                "store them).", name, int((~kept).sum()))
    return vertices[kept], rank[first][faces]


def drop_repeated_faces(faces: np.ndarray, name: str) -> np.ndarray:
    """``faces`` (F, 3) without triangles that repeat a vertex and without second copies of a triangle (exported
    and scanned meshes have them; a copy makes its edges look non-manifold), with a warning naming ``name`` for
    the copies. The kept faces stay in order. → (F', 3)."""
    faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 2] != faces[:, 0])]
    _, first = np.unique(np.sort(faces, 1), axis=0, return_index=True)
    if len(first) < len(faces):
        log.warning("%s: dropped %d repeated triangles.", name, len(faces) - len(first))
        faces = faces[np.sort(first)]
    return faces


def consistent_winding(vertices: np.ndarray, faces: np.ndarray, name: str,
                       error: type[UserInputError] = UserInputError) -> np.ndarray:
    """``faces`` (F, 3) wound alike in each connected component, every interior edge run once each way (Γ and the
    normals follow the winding): the triangles wound against their neighbours are turned to agree with the
    majority of their component, with a warning naming ``name``; one sentence for a component with no consistent
    winding (a Möbius band: no orientation, so no Γ). Consistent faces come back unchanged. → (F, 3)."""
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    if mesh.is_winding_consistent:
        return faces
    trimesh.repair.fix_winding(mesh)  # each component made to agree with one of its faces
    if not mesh.is_winding_consistent:
        raise error(f"{name} is not orientable (its faces cannot all be wound alike, like a Möbius band's); a "
                    "current needs an oriented surface.")
    fixed = np.array(mesh.faces, np.int64)
    turned = (fixed != faces).any(1)
    labels = trimesh.graph.connected_component_labels(mesh.face_adjacency, node_count=len(faces))
    for part in np.unique(labels):  # keep the orientation most of each component's faces had
        members = labels == part
        if turned[members].sum() > members.sum() / 2:
            fixed[members] = fixed[members][:, ::-1]
            turned[members] = ~turned[members]
    log.warning("%s: %d of %d triangles were wound against their neighbours; turned them to agree with the rest.",
                name, int(turned.sum()), len(faces))
    return fixed
