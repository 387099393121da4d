"""Human-part datasets for reconstruction (paper §5.2): heads, hands, forearms, arms, torsos and feet cut
from full bodies, preprocessed as the authors did for FAUST, written as
``<root>/<source>/<category>/NNN.ply``.

Two sources share one pipeline (all bodies of a source share one topology, so parts correspond by index):

- ``anny``: bodies generated offline with the Anny body model (``pip install .[anny]``; MakeHuman's CC0
  assets ship inside the package) with random phenotypes and mild random poses, cut by skinning weights
  (each face goes to the bone that dominates its vertices' weights).
- ``faust``: the FAUST meshes of the human segmentation benchmark (``meshes/train/faust/*.ply`` with
  ``segs/train/faust/faust_corrected.txt``, one label per face), for users who have it.

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
from pathlib import Path

import numpy as np
import scipy.sparse
import trimesh
from scipy.sparse.csgraph import connected_components

from deepcurrents.errors import UserInputError

log = logging.getLogger(__name__)

CATEGORIES = ("heads", "hands", "forearms", "arms", "torsos", "feet")

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


class DatasetError(UserInputError):
    """A dataset that is missing or malformed (the message says how to build or fix it)."""


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


def split_bodies(bodies: Sequence[np.ndarray], faces: np.ndarray, category_faces: dict[str, np.ndarray]):
    """Parts of every body for each category: {category: (list of vertex arrays, part faces, scale)}.

    bodies: list of (V, 3) vertex arrays of one topology ``faces`` (F, 3); category_faces: face indices
    of each category's part (already reduced to one connected component).
    """
    out = {}
    for name, idx in category_faces.items():
        used, sub_faces = cut_part(bodies[0], faces, idx)
        parts, scale = normalise_category([np.asarray(b, np.float64)[used] for b in bodies])
        out[name] = (parts, sub_faces, scale)
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
        mesh = trimesh.load(path, process=False, force="mesh")
        if faces is None:
            faces = np.asarray(mesh.faces, np.int64)
        elif not np.array_equal(faces, mesh.faces):
            raise DatasetError(f"FAUST mesh '{path}' does not share the first mesh's triangles "
                               "(registrations must have one topology).")
        bodies.append(np.asarray(mesh.vertices, np.float64))
    labels = np.loadtxt(seg_file, dtype=np.int64).reshape(-1)
    if len(labels) != len(faces):
        raise DatasetError(f"'{seg_file}' has {len(labels)} labels but the meshes have {len(faces)} faces.")
    return bodies, faces, labels


def faust_parts(root: str | Path, categories: Sequence[str] = CATEGORIES) -> dict:
    """The human parts of FAUST, preprocessed (see the module docstring)."""
    bodies, faces, labels = load_faust(root)
    chosen = {c: select_faces(faces, labels == FAUST_LABELS[c]) for c in categories}
    return split_bodies(bodies, faces, chosen)


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


def anny_face_bones(model) -> tuple[np.ndarray, np.ndarray]:
    """(dominant bone index per face (F,), hidden-surface mask (F,)) from skinning weights and Anny's
    texture segmentation."""
    from anny.face_segmentation import get_face_segmentation_mask

    faces = model.get_triangular_faces().cpu().numpy().astype(np.int64)
    weights = model.vertex_bone_weights.cpu().numpy()
    bones = model.vertex_bone_indices.cpu().numpy()
    per_vertex = np.zeros((weights.shape[0], len(model.bone_labels)))
    rows = np.repeat(np.arange(len(weights)), weights.shape[1])
    np.add.at(per_vertex, (rows, bones.ravel()), weights.ravel())
    dominant = per_vertex[faces].sum(1).argmax(1)
    hidden = get_face_segmentation_mask(model, ANNY_HIDDEN).cpu().numpy()
    return dominant, hidden


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
               pose_degrees: float = 6.0) -> dict:
    """Generated human parts: {category: (parts, faces, scale)} for ``num`` Anny bodies."""
    model = model if model is not None else anny_model()
    faces = model.get_triangular_faces().cpu().numpy().astype(np.int64)
    dominant, hidden = anny_face_bones(model)
    names = np.asarray(model.bone_labels)
    chosen = {}
    for c in categories:
        bone_ok = np.array([re.match(ANNY_BONES[c], n) is not None for n in names])  # 104 bone names
        chosen[c] = select_faces(faces, bone_ok[dominant] & ~hidden)
    bodies = anny_bodies(model, num, seed, pose_degrees)
    return split_bodies(bodies, faces, chosen)


# ---------------------------------------------------------------------------------------------- dataset files

def dataset_path(root: str | Path, source: str, category: str, index: int) -> Path:
    """``root/source/category/NNN.ply``; DatasetError (saying how to build it) when it is not there."""
    folder = Path(root) / source / category
    if not folder.is_dir():
        hint = "run `make data`" if source == "anny" else \
            f"run `python -m deepcurrents.data.human_parts --source {source} ...`"
        raise DatasetError(f"Dataset directory '{folder}' does not exist; {hint} to build it.")
    files = sorted(folder.glob("*.ply"))
    if not files:
        raise DatasetError(f"Dataset directory '{folder}' has no .ply meshes; run `make data` to build it.")
    if not 0 <= index < len(files):
        raise DatasetError(f"data.index={index} is out of range: '{folder}' has {len(files)} meshes "
                           f"(0–{len(files) - 1}).")
    return files[index]


if __name__ == "__main__":  # ``python -m deepcurrents.data.human_parts`` is kept as an alias of the command
    from deepcurrents.cli.make_dataset import main

    main()
