"""Triangle-mesh files: one reader with the checks every caller needs (exists, readable, has triangles,
finite coordinates). Callers add what is particular to them (a reconstruction target must have a boundary,
a family mesh must match the family's topology)."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import trimesh

from deepcurrents.errors import UserInputError

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
    return mesh


def clean_faces(vertices: np.ndarray, faces: np.ndarray, name: str,
                error: type[UserInputError] = UserInputError) -> np.ndarray:
    """``faces`` (F, 3) of a mesh file as a surface with boundary needs them, the vertices untouched: triangles
    with a repeated vertex dropped; triangles written twice dropped and triangles wound against their neighbours
    turned to agree with the majority (each with a warning naming ``name``: exported and scanned meshes have
    both); one sentence if no consistent winding exists (a Möbius band: no orientation, so no Γ). → (F', 3)."""
    faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 2] != faces[:, 0])]
    _, first = np.unique(np.sort(faces, 1), axis=0, return_index=True)
    if len(first) < len(faces):
        log.warning("%s: dropped %d repeated triangles.", name, len(faces) - len(first))
        faces = faces[np.sort(first)]
    mesh = trimesh.Trimesh(vertices, faces, process=False)
    if mesh.is_winding_consistent:
        return faces
    trimesh.repair.fix_winding(mesh)
    if not mesh.is_winding_consistent:
        raise error(f"{name} is not orientable (its faces cannot all be wound alike, like a Möbius band's); a "
                    "current needs an oriented surface.")
    fixed = np.asarray(mesh.faces, np.int64)
    turned = int((fixed != faces).any(1).sum())
    if turned > len(faces) / 2:  # keep the orientation most faces had
        fixed, turned = np.ascontiguousarray(fixed[:, ::-1]), len(faces) - turned
    log.warning("%s: %d of %d triangles were wound against their neighbours; turned them to agree with the rest.",
                name, turned, len(faces))
    return fixed
