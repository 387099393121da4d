"""Triangle-mesh files: one reader with the checks every caller needs (exists, readable, has triangles,
finite coordinates). Callers add what is particular to them (a reconstruction target must have a boundary,
a family mesh must match the family's topology)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from deepcurrents.errors import UserInputError


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
