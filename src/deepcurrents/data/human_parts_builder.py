"""Building the human-part datasets for reconstruction (paper §5.2): heads, hands, forearms, arms, torsos and feet cut
from full bodies, preprocessed as the authors did for FAUST, written as
``<root>/<source>/<category>/NNN.ply``.

Two sources share one pipeline (all bodies of a source share one topology, so parts correspond by index):

- ``anny``: bodies generated offline with the Anny body model (``pip install .[anny]``; MakeHuman's CC0
  assets ship inside the package) with random phenotypes and mild random poses, cut by skinning weights.
- ``faust``: the FAUST meshes of the human segmentation benchmark (``meshes/train/faust/*.ply`` with
  ``segs/train/faust/faust_corrected.txt``, one label per face), for users who have it.

Borders (``border="smooth"``, the default): each part is cut along the level set ``u = 1/2`` of a smooth
per-vertex scalar u, interpolated inside the triangles it crosses, so Γ is a smooth curve and not a sawtooth of
mesh edges. For Anny, u is the part's summed skinning weight (the share of the part's bones); for FAUST, the
part's per-face label smoothed onto the vertices. Crossing points that fall very close to a vertex are snapped
onto it, so the cut leaves no slivers. The cut is computed once on the shared topology as fixed affine
combinations of body vertices (``PartCut``), so parts still correspond vertex by vertex across bodies.
``border="faces"`` is the former cut along mesh edges (each face goes to the bone, or label, that dominates it).

Preprocessing per category (authors' ``preprocess_data.py``): keep the part's largest connected component,
centre each mesh, rotate it onto the category's first mesh (Kabsch on corresponding vertices), then one scale
per category so that every mesh fits in [-0.5, 0.5]^3.

Command line: ``deepcurrents-make-dataset --source anny --num 100 --out data`` (``deepcurrents.cli.make_dataset``).
"""

from __future__ import annotations

import json
import logging
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.sparse
import trimesh
from scipy.sparse.csgraph import connected_components

from deepcurrents.data.human_parts import CATEGORIES, DatasetError
from deepcurrents.geometry.topology import border_edges

log = logging.getLogger(__name__)

# FAUST segmentation labels of the categories (the authors' seg_idx)
FAUST_LABELS = {"heads": 1, "hands": 2, "forearms": 3, "arms": 4, "torsos": 5, "feet": 8}

# Anny bones of each category (one side for limbs: the left one)
ANNY_BONES = {
    "heads": r"^(head|eye\.[LR]|neck02|neck03)$",
    "hands": r"^(wrist|finger\d-\d|metacarpal\d)\.L$",
    "forearms": r"^lowerarm0[12]\.L$",
    "arms": r"^upperarm0[12]\.L$",
    "torsos": r"^(spine0\d|pelvis\.[LR]|clavicle\.[LR]|shoulder01\.[LR]|neck01)$",
    "feet": r"^(foot|toe\d-\d)\.L$",
}
# inner surfaces of the Anny mesh (eyeballs, mouth) that a scan would not see
ANNY_HIDDEN = ["eye_back.L", "eye_front.L", "eye_back.R", "eye_front.R", "eye_cavity.R", "eye_cavity.L",
               "mouth_cavity", "tongue"]


def largest_component(faces: np.ndarray) -> np.ndarray:
    """Indices of the faces in the largest edge-connected component (by face count). (F, 3) → (F',)."""
    if len(faces) == 0:
        return np.zeros(0, dtype=np.int64)
    adj = trimesh.graph.face_adjacency(faces)
    graph = scipy.sparse.coo_matrix((np.ones(len(adj)), (adj[:, 0], adj[:, 1])), shape=(len(faces),) * 2)
    _, labels = connected_components(graph, directed=False)
    return np.flatnonzero(labels == np.bincount(labels).argmax())


def cut_part(vertices: np.ndarray, faces: np.ndarray,
             face_index: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The submesh made of ``faces[face_index]`` with unused vertices dropped.

    → (vertex index into the full mesh (V',), faces (F', 3) indexing the kept vertices).
    """
    sub = faces[face_index]
    used = np.unique(sub)
    remap = np.full(len(vertices), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return used, remap[sub]


def kabsch_rotation(source: np.ndarray, target: np.ndarray) -> np.ndarray:
    """The rotation R minimising Σ |R s_i − t_i|² for centred corresponding points (N, 3) → (3, 3)."""
    h = source.T @ target
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(vt.T @ u.T))
    return vt.T @ np.diag([1.0, 1.0, d]) @ u.T


def normalise_category(parts: Sequence[np.ndarray],
                       half_extent: float = 0.5) -> tuple[list[np.ndarray], float]:
    """Centre each part's vertices (same vertex order in every part), rotate onto the first (Kabsch), and
    scale all by one factor so that every part fits in [-half_extent, half_extent]^3. → (parts, scale)."""
    centred = [p - p.mean(0) for p in parts]
    ref = centred[0]
    aligned = [c @ kabsch_rotation(c, ref).T for c in centred]
    scale = max(float(np.abs(a).max()) for a in aligned) / half_extent
    return [a / scale for a in aligned], scale


def split_bodies(bodies: Sequence[np.ndarray], category_cuts: dict[str, PartCut]) -> dict:
    """Parts of every body for each category: {category: (list of vertex arrays, part faces, scale)}.

    bodies: list of (V, 3) vertex arrays of one topology; category_cuts: each category's cut of it.
    """
    out = {}
    for name, cut in category_cuts.items():
        parts, scale = normalise_category([cut.apply(b) for b in bodies])
        out[name] = (parts, cut.faces, scale)
    return out


def write_parts(parts_by_category: dict, root: Path, source: str, meta: dict | None = None) -> list[Path]:
    """Writes ``root/source/category/NNN.ply`` (and a meta.json per category). → the files written."""
    written = []
    for name, (parts, faces, scale) in parts_by_category.items():
        folder = Path(root) / source / name
        folder.mkdir(parents=True, exist_ok=True)
        for i, verts in enumerate(parts):
            path = folder / f"{i:03d}.ply"
            trimesh.Trimesh(verts, faces, process=False).export(path)
            written.append(path)
        info = {"source": source, "category": name, "count": len(parts), "scale": scale,
                "faces": int(len(faces)), "vertices": int(len(parts[0]))}
        (folder / "meta.json").write_text(json.dumps({**info, **(meta or {})}, indent=2))
    return written


def select_faces(faces: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """Face indices where ``keep[face]`` holds, reduced to their largest connected component."""
    idx = np.flatnonzero(keep)
    return idx[largest_component(faces[idx])]


# ---------------------------------------------------------------------------------------------- part cuts

BORDERS = ("smooth", "faces")


@dataclass(frozen=True)
class PartCut:
    """A part of a mesh topology: its vertices as fixed affine combinations of the full mesh's vertices and
    its triangles. Applied to every body of the topology, it yields corresponding parts.

    weights: (V', V) sparse, rows sum to one (a row with one entry is a kept vertex, two entries a point on an
    edge); faces: (F', 3) indexing the part's vertices.
    """

    weights: scipy.sparse.csr_matrix
    faces: np.ndarray

    def apply(self, vertices: np.ndarray) -> np.ndarray:
        """The part's vertices on one body. (V, 3) → (V', 3)."""
        return np.asarray(self.weights @ np.asarray(vertices, np.float64))

    @classmethod
    def from_faces(cls, num_vertices: int, faces: np.ndarray, face_index: np.ndarray) -> PartCut:
        """The part made of ``faces[face_index]`` (a cut along mesh edges)."""
        used, sub = cut_part(np.empty((num_vertices, 0)), faces, face_index)
        sel = scipy.sparse.csr_matrix((np.ones(len(used)), (np.arange(len(used)), used)),
                                      shape=(len(used), num_vertices))
        return cls(sel, sub)


def _snap_values(faces: np.ndarray, values: np.ndarray, snap: float) -> np.ndarray:
    """``values`` with those vertices set to exactly 0 where a crossing of the zero level on one of their
    edges lies within ``snap`` (fraction of the edge) of them: the cut then passes through the vertex instead
    of leaving a sliver."""
    edges = np.unique(np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1), axis=0)
    a, b = values[edges[:, 0]], values[edges[:, 1]]
    cross = a * b < 0
    t = a[cross] / (a[cross] - b[cross])  # where along (e0 → e1) the field is 0
    out = values.copy()
    out[edges[cross][t < snap, 0]] = 0.0
    out[edges[cross][t > 1 - snap, 1]] = 0.0
    return out


def _pinched_vertices(faces: np.ndarray) -> np.ndarray:
    """Vertices where a triangle mesh is pinched: more than two border edges meet there. (F, 3) → (K,)."""
    ids, deg = np.unique(border_edges(faces).ravel(), return_counts=True)
    return ids[deg > 2]


def level_set_cut(vertices: np.ndarray, faces: np.ndarray, values: np.ndarray, snap: float = 0.2,
                  keep_faces: np.ndarray | None = None) -> PartCut:
    """The part ``{values ≥ 0}`` of a triangle mesh, cut along the zero level set of the piecewise-linear
    field ``values``: each crossed triangle is split at the iso-line, so the part's border lies exactly on
    the level set, a smooth curve when the field is smooth.

    vertices: (V, 3) a reference body (chooses the shorter diagonal where a quad is split); faces: (F, 3);
    values: (V,) the field; snap: crossings closer than this fraction of an edge to a vertex go onto the
    vertex (no sliver triangles; the border then deviates from the level set by at most ``snap`` of an edge);
    keep_faces: (F,) bool, faces allowed in the part (others and their pieces are dropped). The part is
    reduced to its largest connected component.
    """
    vertices = np.asarray(vertices, np.float64)
    faces = np.asarray(faces, np.int64)
    values = np.asarray(values, np.float64)
    snapped = _snap_values(faces, values, snap)
    for _ in range(10):
        # a snapped saddle vertex would pinch the part (or, once reduced to one component, cut it in two
        # there): such vertices keep their own value. Part vertices below V are the mesh's own.
        weights, split_faces, positive, _ = _split_at_zero(vertices, faces, snapped, values, keep_faces)
        part_faces = split_faces[positive]
        pinched = _pinched_vertices(part_faces)
        pinched = pinched[pinched < len(vertices)]
        pinched = pinched[(snapped[pinched] == 0) & (values[pinched] != 0)]
        if len(pinched) == 0:
            break
        snapped[pinched] = values[pinched]
    part_faces = part_faces[largest_component(part_faces)]
    used = np.unique(part_faces)
    remap = np.full(weights.shape[0], -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return PartCut(weights[used], remap[part_faces])


def _split_at_zero(vertices: np.ndarray, faces: np.ndarray, values: np.ndarray, original: np.ndarray,
                   keep_faces: np.ndarray | None
                   ) -> tuple[scipy.sparse.csr_matrix, np.ndarray, np.ndarray, np.ndarray]:
    """The mesh split along the zero level set of ``values`` (exact zeros after snapping, see ``level_set_cut``):
    every triangle the iso-line crosses is cut into its pieces on either side, which share the crossing points.

    → (weights (V + P, V): the mesh's vertices then the P crossing points; faces (F', 3) of both sides, indexing
    them; positive (F',) bool: the face lies in {values ≥ 0}; origin (F',): the face of ``faces`` each is a piece
    of). Faces outside ``keep_faces`` and their pieces are dropped."""
    sign = np.sign(values).astype(np.int64)[faces]  # (F, 3)
    pos, neg = (sign > 0).sum(1), (sign < 0).sum(1)
    # all-zero triangles (a snapped triangle) follow the mean of the unsnapped field
    flat = (pos == 0) & (neg == 0)
    split = (pos > 0) & (neg > 0)
    inside = ((neg == 0) & (pos > 0) | flat & (original[faces].mean(1) >= 0)) & ~split
    whole = ~split
    if keep_faces is not None:
        whole &= keep_faces
        split &= keep_faces
    new_faces, new_side, new_origin = [faces[whole]], [inside[whole]], [np.flatnonzero(whole)]
    points: dict[tuple[int, int], int] = {}  # edge (inside vertex, outside vertex) → new point id
    n = len(vertices)
    point_rows: list[tuple[int, int, float]] = []

    def crossing(i: int, o: int) -> int:
        key = (i, o)
        if key not in points:
            t = values[i] / (values[i] - values[o])  # in [snap, 1 − snap] after snapping
            points[key] = n + len(points)
            point_rows.append((i, o, float(t)))
        return points[key]

    def point(p: int) -> np.ndarray:
        i, o, t = point_rows[p - n]
        return vertices[i] + (vertices[o] - vertices[i]) * t

    def quad(p: int, b: int, c: int, q: int) -> np.ndarray:
        """The quad (p, b, c, q) (p on the edge before b, q on the edge after c) in two triangles along its
        shorter diagonal."""
        if np.linalg.norm(point(p) - vertices[c]) <= np.linalg.norm(point(q) - vertices[b]):
            return np.array([[p, b, c], [p, c, q]])
        return np.array([[p, b, q], [b, c, q]])

    def add(tris: np.ndarray, positive: bool) -> None:
        new_faces.append(tris)
        new_side.append(np.full(len(tris), positive))
        new_origin.append(np.full(len(tris), f))

    for f in np.flatnonzero(split):
        tri, s = faces[f], sign[f]
        # the odd vertex first: the zero one, else the one alone on its side
        odd = 0 if (s == 0).any() else (1 if pos[f] == 1 else -1)
        k = int(np.flatnonzero(s == odd)[0])
        a, b, c = tri[k], tri[(k + 1) % 3], tri[(k + 2) % 3]  # cyclic order kept: orientation is kept
        sa, sb = values[a], values[b]
        if sa == 0:  # the iso-line runs from a to a point on bc
            if sb > 0:
                p = crossing(b, c)
                add(np.array([[a, b, p]]), True)
                add(np.array([[a, p, c]]), False)
            else:
                p = crossing(c, b)
                add(np.array([[a, p, c]]), True)
                add(np.array([[a, b, p]]), False)
        elif sa > 0:  # a alone inside: the corner triangle inside, the quad outside
            pb, pc = crossing(a, b), crossing(a, c)
            add(np.array([[a, pb, pc]]), True)
            add(quad(pb, b, c, pc), False)
        else:  # a alone outside: the quad (pb, b, c, pc) inside, the corner outside
            pb, pc = crossing(b, a), crossing(c, a)
            add(quad(pb, b, c, pc), True)
            add(np.array([[a, pb, pc]]), False)
    all_faces = np.concatenate(new_faces).astype(np.int64)
    # the weights: identity rows for the mesh's vertices, then (1 − t, t) rows for the crossing points
    i, o, t = (np.array(x).reshape(-1) for x in zip(*point_rows, strict=True)) if point_rows else \
        (np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0))
    ids = np.arange(n, n + len(point_rows))
    full = scipy.sparse.csr_matrix(
        (np.concatenate([np.ones(n), 1.0 - t, t]),
         (np.concatenate([np.arange(n), ids, ids]), np.concatenate([np.arange(n), i, o]).astype(np.int64))),
        shape=(n + len(point_rows), n))
    return full, all_faces, np.concatenate(new_side), np.concatenate(new_origin)


def smooth_label_field(faces: np.ndarray, in_part: np.ndarray, num_vertices: int,
                       iterations: int = 8) -> np.ndarray:
    """A smooth per-vertex field from a per-face label: the share of each vertex's faces in the part,
    averaged with its neighbours ``iterations`` times (lazy umbrella smoothing). (F,) bool → (V,) in [0, 1]."""
    count = np.bincount(faces.ravel(), minlength=num_vertices).astype(np.float64)
    share = np.bincount(faces[in_part].ravel(), minlength=num_vertices) / np.maximum(count, 1)
    edges = np.unique(np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1), axis=0)
    adj = scipy.sparse.coo_matrix((np.ones(2 * len(edges)), (edges.ravel(), edges[:, ::-1].ravel())),
                                  shape=(num_vertices,) * 2).tocsr()
    deg = np.maximum(np.asarray(adj.sum(1)).ravel(), 1)
    for _ in range(iterations):
        share = 0.5 * share + 0.5 * (adj @ share) / deg
    return share


# ---------------------------------------------------------------------------------------------- FAUST

def load_faust(root: str | Path) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
    """FAUST as in the segmentation benchmark: ``root/meshes/train/faust/*.ply`` (one topology) and
    ``root/segs/train/faust/faust_corrected.txt`` (one label per face). → (bodies, faces, face labels)."""
    root = Path(root)
    mesh_dir = root / "meshes" / "train" / "faust"
    seg_file = root / "segs" / "train" / "faust" / "faust_corrected.txt"
    if not mesh_dir.is_dir():
        raise DatasetError(f"FAUST meshes not found: '{mesh_dir}' is not a directory (expected the "
                           "segmentation benchmark layout meshes/train/faust/*.ply).")
    if not seg_file.is_file():
        raise DatasetError(f"FAUST segmentation not found: '{seg_file}' does not exist.")
    files = sorted(p for p in mesh_dir.iterdir() if p.suffix.lower() in (".ply", ".obj", ".off"))
    if not files:
        raise DatasetError(f"No FAUST meshes (.ply/.obj/.off) in '{mesh_dir}'.")
    bodies, faces = [], None
    for path in files:
        try:  # not geometry.meshes.read_mesh: registrations are read as they are (no vertex merging)
            mesh = trimesh.load(path, process=False, force="mesh")
        except Exception as err:  # trimesh raises many kinds for unreadable files
            raise DatasetError(f"FAUST mesh '{path}' could not be read as a triangle mesh "
                               f"({type(err).__name__}: {err}).") from None
        if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
            raise DatasetError(f"FAUST mesh '{path}' holds no triangles.")
        if not np.isfinite(np.asarray(mesh.vertices)).all():
            raise DatasetError(f"FAUST mesh '{path}' has NaN or infinite vertex coordinates.")
        if faces is None:
            faces = np.asarray(mesh.faces, np.int64)
        elif not np.array_equal(faces, mesh.faces):
            raise DatasetError(f"FAUST mesh '{path}' does not share the first mesh's triangles "
                               "(registrations must have one topology).")
        bodies.append(np.asarray(mesh.vertices, np.float64))
    try:
        labels = np.loadtxt(seg_file, dtype=np.int64).reshape(-1)
    except ValueError as err:  # words, decimals or ragged rows where one integer label per face belongs
        raise DatasetError(f"'{seg_file}' must hold one integer label per face ({err}).") from None
    if len(labels) != len(faces):
        raise DatasetError(f"'{seg_file}' has {len(labels)} labels but the meshes have {len(faces)} faces.")
    return bodies, faces, labels


def check_border(border: str) -> None:
    """DatasetError unless ``border`` is one of BORDERS."""
    if border not in BORDERS:
        raise DatasetError(f"border='{border}' is not one of {', '.join(BORDERS)}.")


def faust_parts(root: str | Path, categories: Sequence[str] = CATEGORIES, border: str = "smooth") -> dict:
    """The human parts of FAUST, preprocessed (see the module docstring)."""
    check_border(border)
    bodies, faces, labels = load_faust(root)
    cuts = {}
    for c in categories:
        in_part = labels == FAUST_LABELS[c]
        if border == "faces":
            cuts[c] = PartCut.from_faces(len(bodies[0]), faces, select_faces(faces, in_part))
        else:
            field = smooth_label_field(faces, in_part, len(bodies[0]))
            cuts[c] = level_set_cut(bodies[0], faces, field - 0.5)
    return split_bodies(bodies, cuts)


# ---------------------------------------------------------------------------------------------- Anny

def anny_model():
    """The Anny body model on CPU with torch linear-blend skinning (no compiled kernels needed).
    Raises DatasetError with the install command when the optional package is missing."""
    try:
        import anny  # noqa: F401
    except ImportError as err:
        raise DatasetError("The Anny body model is not installed; run `make data` or "
                           "`pip install -e .[anny]`.") from err
    return anny.Anny(skinning_method="lbs")


def anny_skinning(model) -> tuple[np.ndarray, np.ndarray]:
    """(per-vertex weight of every bone (V, B), rows summing to one; hidden-surface mask per face (F,)) from
    Anny's skinning weights and texture segmentation."""
    from anny.face_segmentation import get_face_segmentation_mask

    weights = model.vertex_bone_weights.cpu().numpy()
    bones = model.vertex_bone_indices.cpu().numpy()
    per_vertex = np.zeros((weights.shape[0], len(model.bone_labels)))
    rows = np.repeat(np.arange(len(weights)), weights.shape[1])
    np.add.at(per_vertex, (rows, bones.ravel()), weights.ravel())
    hidden = get_face_segmentation_mask(model, ANNY_HIDDEN).cpu().numpy().astype(bool)
    return per_vertex, hidden


def anny_bodies(model, num: int, seed: int = 0, pose_degrees: float = 6.0,
                batch: int = 16) -> list[np.ndarray]:
    """``num`` bodies with uniform random phenotypes (gender, age, muscle, weight, height, proportions in
    [0, 1]) and mild random poses (each bone rotated by a random vector, σ = ``pose_degrees`` per axis).
    → list of (V, 3) vertex arrays."""
    import roma
    import torch

    gen = torch.Generator().manual_seed(seed)
    joints = int(model.bone_count)
    out = []
    for start in range(0, num, batch):
        b = min(batch, num - start)
        rotvec = torch.randn(b, joints, 3, generator=gen, dtype=torch.float64) * np.deg2rad(pose_degrees)
        rotvec[:, 0] = 0.0  # no global rotation (the root); alignment removes it anyway
        pose = torch.eye(4, dtype=torch.float64).repeat(b, joints, 1, 1)
        pose[..., :3, :3] = roma.rotvec_to_rotmat(rotvec)
        phenotype = torch.rand(b, len(model.phenotype_labels), generator=gen, dtype=torch.float64)
        with torch.no_grad():
            verts = model(pose_parameters=pose.to(model.dtype), phenotype_kwargs=phenotype.to(model.dtype))
        out += list(verts["vertices"].double().cpu().numpy())
    return out


def anny_parts(num: int = 100, seed: int = 0, categories: Sequence[str] = CATEGORIES, model=None,
               pose_degrees: float = 6.0, border: str = "smooth") -> dict:
    """Generated human parts: {category: (parts, faces, scale)} for ``num`` Anny bodies.

    border: ``"smooth"`` cuts along the level set 1/2 of the part's summed skinning weight; ``"faces"`` gives
    each face to the bone that dominates its vertices' weights (the former sawtooth cut)."""
    check_border(border)
    model = model if model is not None else anny_model()
    faces = model.get_triangular_faces().cpu().numpy().astype(np.int64)
    per_vertex, hidden = anny_skinning(model)
    names = np.asarray(model.bone_labels)
    bodies = anny_bodies(model, num, seed, pose_degrees)
    cuts = {}
    for c in categories:
        bone_ok = np.array([re.match(ANNY_BONES[c], n) is not None for n in names])  # 104 bone names
        if border == "faces":
            dominant = per_vertex[faces].sum(1).argmax(1)
            cuts[c] = PartCut.from_faces(len(per_vertex), faces, select_faces(faces, bone_ok[dominant] & ~hidden))
        else:
            share = per_vertex[:, bone_ok].sum(1)  # (V,) the part's share of the skinning
            cuts[c] = level_set_cut(bodies[0], faces, share - 0.5, keep_faces=~hidden)
    return split_bodies(bodies, cuts)
