"""Harmonic skinning: boundary-loop displacements carried to the whole mesh (paper §5.3, augmentation).

Every boundary vertex is a handle. The displacement field d of the mesh is the discrete harmonic
function (cotangent Laplacian, libigl) that equals the prescribed handle displacements d_B on Γ:

    L_II d_I = −L_IB d_B,    d_B given,

so d = W d_B with skinning weights W (V, H): W restricted to the handles is the identity, and every row of
W sums to one (constants are harmonic), so a uniform translation of Γ translates the whole mesh.

``L_II`` is factorised once per mesh (sparse LU, lazily, once per process so DataLoader workers each own
their factor) and every augmentation step is one solve with three right-hand sides.
"""

from __future__ import annotations

import igl
import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.sparse.linalg import splu

from deepcurrents.errors import UserInputError


class HarmonicSkinning:
    """Harmonic skinning weights of a triangle mesh with the given handle vertices.

    Args:
        vertices: (V, 3) float array.
        faces: (F, 3) int array.
        handles: (H,) indices of the handle vertices (the boundary loops' vertices, concatenated).
        name: how error messages name the mesh.
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, handles: np.ndarray, name: str = "mesh"):
        self.vertices = np.asarray(vertices, dtype=np.float64)
        self.faces = np.asarray(faces, dtype=np.int64)
        self.handles = np.asarray(handles, dtype=np.int64)
        self.name = name
        n = len(self.vertices)
        if len(self.handles) == 0:
            raise UserInputError(f"Mesh '{name}' has no boundary vertices to use as skinning handles.")
        if len(np.unique(self.handles)) != len(self.handles):
            raise UserInputError(f"Mesh '{name}': the skinning handles contain repeated vertices.")
        is_handle = np.zeros(n, dtype=bool)
        is_handle[self.handles] = True
        self.free = np.flatnonzero(~is_handle)  # (I,) interior vertices
        lap = sp.csr_matrix(igl.cotmatrix(self.vertices, self.faces))
        # L_II is singular exactly when some connected part has no handle (or a vertex is in no face)
        _, part = connected_components(lap != 0, directed=False)
        if not np.isin(part, part[self.handles]).all():
            raise UserInputError(
                f"Mesh '{name}' cannot be skinned: a connected part of it has no boundary vertex "
                "(or it has vertices in no face); keep only its component with boundary."
            )
        self._l_ii = (-lap[self.free][:, self.free]).tocsc()  # SPD when every component touches a handle
        self._l_ib = lap[self.free][:, self.handles].tocsc()
        self._lu = None

    @property
    def num_vertices(self) -> int:
        return len(self.vertices)

    def _factor(self):
        if self._lu is None and len(self.free):
            self._lu = splu(self._l_ii)
        return self._lu

    def __getstate__(self) -> dict:
        state = dict(self.__dict__)
        state["_lu"] = None  # SuperLU objects do not pickle; each process factorises once
        return state

    def propagate(self, handle_displacements: np.ndarray) -> np.ndarray:
        """Displacements of all vertices from those of the handles. (H, k) → (V, k)."""
        d_b = np.asarray(handle_displacements, dtype=np.float64)
        flat = d_b.reshape(len(self.handles), -1)  # (H, k)
        out = np.zeros((self.num_vertices, flat.shape[1]), dtype=np.float64)
        out[self.handles] = flat
        if len(self.free):
            # −L_II d_I = L_IB d_B  ⇔  L_II d_I = −L_IB d_B
            out[self.free] = self._factor().solve(np.asarray(self._l_ib @ flat))
        return out.reshape((self.num_vertices,) + d_b.shape[1:])

    def weights(self) -> np.ndarray:
        """The dense skinning weights W (V, H): row v says how vertex v follows each handle."""
        return self.propagate(np.eye(len(self.handles)))

    def deform(self, handle_positions: np.ndarray) -> np.ndarray:
        """The mesh's vertices after moving the handles to ``handle_positions`` (H, 3). → (V, 3)."""
        return self.vertices + self.propagate(np.asarray(handle_positions) - self.vertices[self.handles])
