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

    Walks edges, not vertices: where loops touch at a vertex (two border edges leave it), each edge is still used
    once, and whenever the walk comes back to a vertex it has passed, the stretch since then is cut off as a loop
    of its own, so every loop is simple whatever the faces' order. Border edges that close no loop
    (inconsistently oriented faces) and loops of fewer than 3 vertices are left out.
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
        walk, where, e = [int(edges[first, 0])], {int(edges[first, 0]): 0}, first
        while e is not None:
            used[e] = True
            v = heads[e]
            if v in where:  # a closed stretch: from v's first visit back to v
                k = where[v]
                if len(walk) - k >= 3:
                    loops.append(np.asarray(walk[k:]))
                for u in walk[k + 1:]:
                    del where[u]
                del walk[k + 1:]
            else:
                where[v] = len(walk)
                walk.append(v)
            e = next((k for k in outgoing.get(walk[-1], ()) if not used[k]), None)
    return loops
