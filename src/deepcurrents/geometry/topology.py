"""Triangle-mesh topology from faces alone: the border edges (used by one face only) and the border loops
they form. Shared by the targets (Γ of a mesh), the meshing (closing a cut border onto Γ) and the metrics
(the boundary error)."""

from __future__ import annotations

from dataclasses import dataclass

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
    """Border loops of a triangle mesh as vertex index arrays (M_i,), each following its faces' orientation: the
    closed walks of the border edges (``edge_walks``; loops that touch at a vertex stay apart, whatever the faces'
    order). Border edges that close no loop (inconsistently oriented faces) and loops of fewer than 3 vertices are
    left out."""
    walks = edge_walks(border_edges(faces).tolist(), directed=True)
    return [np.asarray(walk) for walk, _, closed in walks if closed and len(walk) >= 3]


def edge_walks(edges: list[tuple[int, int]] | list[list[int]], directed: bool
               ) -> list[tuple[list[int], list[bool], bool]]:
    """Splits edges (a, b) into simple closed loops and open chains, each edge used once. → (vertices, along,
    closed) per walk, ``along[i]`` whether step i runs along its edge's own direction a → b.

    ``directed``: steps only go along edges (a mesh's border); otherwise either way, along an edge where one leaves
    (curve segments written in either direction), and walks start from the open ends first. Whenever a walk comes
    back to a vertex it has passed, the stretch since then is cut off as a closed loop, so loops that touch at a
    vertex stay apart; what remains when a walk cannot go on is an open chain (closed False)."""
    incident: dict[int, list[int]] = {}
    for e, (a, b) in enumerate(edges):
        incident.setdefault(a, []).append(e)
        if not directed:
            incident.setdefault(b, []).append(e)
    used = [False] * len(edges)
    walks = []
    ends = [] if directed else [u for u, es in incident.items() if len(es) == 1]
    for start in ends + [a for a, _ in edges]:
        walk, where, along, cur = [start], {start: 0}, [], start
        while True:
            free = [e for e in incident.get(cur, ()) if not used[e]]
            if not free:
                break
            e = next((e for e in free if edges[e][0] == cur), free[0])
            used[e] = True
            along.append(edges[e][0] == cur)
            cur = edges[e][1] if edges[e][0] == cur else edges[e][0]
            if cur in where:  # back at a vertex of this walk: the stretch since is a closed loop
                k = where[cur]
                walks.append((walk[k:], along[k:], True))
                for u in walk[k + 1:]:
                    del where[u]
                del walk[k + 1:], along[k:]
            else:
                where[cur] = len(walk)
                walk.append(cur)
        if len(walk) > 1:
            walks.append((walk, along, False))
    return walks


@dataclass(frozen=True)
class SurfaceTopology:
    """Which surface a triangle mesh is: its connected pieces, border loops, Euler characteristic χ = V − E + F and
    genus g (χ = Σ_pieces (2 − 2g_i − b_i) for an oriented surface with b border loops), and whether it is an
    oriented 2-manifold (each edge in at most two faces, run opposite ways), without which g means nothing."""

    components: int
    border_loops: int
    euler_characteristic: int
    genus: int
    manifold: bool

    def describe(self) -> str:
        """In words, e.g. "a disk (genus 0, 1 border loop, χ = 1)"."""
        facts = (f"genus {self.genus}, {self.border_loops} border loop{'s' * (self.border_loops != 1)}, "
                 f"χ = {self.euler_characteristic}")
        if not self.manifold:
            return f"not an oriented manifold ({facts})"
        names = {(1, 0, 1): "a disk", (1, 0, 2): "an annulus", (2, 0, 2): "two disks"}
        name = names.get((self.components, self.genus, self.border_loops))
        if name is None:
            name = "a connected surface" if self.components == 1 else f"a surface in {self.components} pieces"
        return f"{name} ({facts})"


def face_components(faces: np.ndarray, num_vertices: int) -> np.ndarray:
    """The label of each face's connected component, faces sharing a vertex being connected. (F, 3) → (F,)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    rows, cols = np.repeat(faces[:, 0], 2), faces[:, 1:].reshape(-1)
    graph = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(num_vertices, num_vertices))
    return connected_components(graph, directed=False)[1][faces[:, 0]]


def consistently_oriented(faces: np.ndarray) -> bool:
    """Whether no directed edge is run by two faces: every edge with two faces is run in opposite directions by them.
    faces (F, 3)."""
    faces = np.asarray(faces, dtype=np.int64)
    directed = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    return len(np.unique(directed, axis=0)) == len(directed)


def surface_topology(faces: np.ndarray) -> SurfaceTopology:
    """``SurfaceTopology`` of a triangle mesh from its faces (F, 3) alone (unused vertices do not count)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    faces = np.asarray(faces, dtype=np.int64)
    used, local = np.unique(faces, return_inverse=True)
    local = local.reshape(faces.shape)
    directed = np.concatenate([local[:, [0, 1]], local[:, [1, 2]], local[:, [2, 0]]])
    undirected, counts = np.unique(np.sort(directed, 1), axis=0, return_counts=True)
    manifold = bool(counts.max(initial=0) <= 2 and consistently_oriented(faces))
    n = len(used)
    graph = coo_matrix((np.ones(len(undirected)), (undirected[:, 0], undirected[:, 1])), shape=(n, n))
    components = int(connected_components(graph, directed=False)[0]) if n else 0
    chi = n - len(undirected) + len(faces)
    loops = len(border_loops(faces))
    return SurfaceTopology(components, loops, int(chi), int((2 * components - chi - loops) // 2), manifold)
