"""Triangle-mesh topology from faces alone: the border edges (used by one face only) and the border loops
they form. Shared by the targets (Γ of a mesh), the meshing (closing a cut border onto Γ) and the metrics
(the boundary error)."""

from __future__ import annotations

import numpy as np


def first_copies(points: np.ndarray, tolerance: float = 0.0) -> np.ndarray:
    """For each point, the index of the first point at its position: exactly (``tolerance`` 0), or within
    ``tolerance`` (points closer than it, chained, are one). Files store a vertex once per triangle (STL) or per
    edge (OBJ polylines written edge by edge); this joins the copies. (N, d) → (N,) int64, ≤ its own index."""
    n = len(points)
    if tolerance > 0:
        from scipy.sparse import coo_matrix
        from scipy.sparse.csgraph import connected_components
        from scipy.spatial import cKDTree

        pairs = cKDTree(points).query_pairs(tolerance, output_type="ndarray")
        graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
        _, labels = connected_components(graph, directed=False)
    else:
        _, labels = np.unique(points, axis=0, return_inverse=True)
        labels = labels.reshape(-1)
    first = np.full(labels.max() + 1 if n else 0, n, dtype=np.int64)
    np.minimum.at(first, labels, np.arange(n))
    return first[labels]


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
