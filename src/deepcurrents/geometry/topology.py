"""Triangle-mesh topology from faces alone: the border edges (used by one face only) and the border loops
they form. Shared by the targets (Γ of a mesh), the meshing (closing a cut border onto Γ) and the metrics
(the boundary error)."""

from __future__ import annotations

import numpy as np


def border_edges(faces: np.ndarray) -> np.ndarray:
    """The directed edges that belong to one face only, each following its face's orientation.

    faces (F, 3) integer → (E, 2) integer.
    """
    directed = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    _, inv, counts = np.unique(np.sort(directed, 1), axis=0, return_inverse=True, return_counts=True)
    return directed[counts[inv.reshape(-1)] == 1]


def border_loops(faces: np.ndarray) -> list[np.ndarray]:
    """Border loops of a triangle mesh as vertex index arrays (M_i,), each following its faces' orientation.

    Walks edges, not vertices: where two loops touch at a vertex (two border edges leave it), each edge is
    still used once, and the walk splits there into simple loops. Border edges that close no loop
    (inconsistently oriented faces) are left out.
    """
    edges = border_edges(faces)
    outgoing: dict[int, list[int]] = {}
    for e, a in enumerate(edges[:, 0].tolist()):
        outgoing.setdefault(a, []).append(e)
    heads = edges[:, 1].tolist()
    used = np.zeros(len(edges), dtype=bool)
    loops = []
    for first in range(len(edges)):
        if used[first]:
            continue
        start, loop, e = int(edges[first, 0]), [], first
        while True:
            used[e] = True
            loop.append(int(edges[e, 0]))
            v = heads[e]
            if v == start:
                break
            e = next((k for k in outgoing.get(v, ()) if not used[k]), None)
            if e is None:
                break
        if v == start and len(loop) >= 3:
            loops.append(np.asarray(loop))
    return loops
