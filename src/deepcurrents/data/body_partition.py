"""Whole bodies cut into parts whose borders are shared curves, for stitched DeepCurrents (the paper's conclusion:
"stitching together DeepCurrents along their boundaries"): every face of the body in exactly one part, two
neighbouring parts cut along one smooth curve that both use, all parts in the body's own frame.

The parts form a tree rooted at the torso (``BODY_PARTS``). Each part P other than the torso is cut from its parent
along the level set 1/2 of its subtree's share of the skinning, u_P = Σ of the weights of the bones of P and of the
parts below it (the hand's share for the wrist, hand and forearm for the elbow, …), interpolated inside the triangles
it crosses, as the single-part datasets are cut (``human_parts_builder``). The cuts are made one after another on one
refined mesh, so the crossing points of a cut are vertices of both parts it separates. Siblings' cuts cannot cross
(u_A + u_B ≤ 1); a child's share is at most its parent's. Each face belongs to the deepest part whose cut it lies
inside; a stray island of a part (an extra loop of a level set) goes to the neighbour it shares most border with.

Anny's inner surfaces (eyeballs, eye and mouth cavities, tongue) are left out, as a scan would not see them, and the
three openings they leave (the eye sockets, the mouth) are capped by fans to their centroids, so the body is closed
and the head is closed but for the neck. As for the single parts, the whole partition is fixed affine combinations of
the model's vertices (``PartCut``), so every body of the topology gets corresponding parts and loops.

On disk (``write_body``): ``<root>/anny/bodies/NNN/body.ply`` (the closed body), ``parts/<part>.ply`` (each part, its
border exactly its loops), ``loops.json`` (each shared loop once: its name, the two parts it joins, its vertices as
the child part's border runs, in float64, and their indices into body.ply; each part's file, parent and body
vertices; the part of every face of body.ply) and ``loops/<name>.obj`` (each loop as a curve file).
"""

from __future__ import annotations

import json
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.sparse
import trimesh
from scipy.sparse.csgraph import connected_components

from deepcurrents.data.human_parts import DatasetError
from deepcurrents.data.human_parts_builder import _pinched_vertices, _snap_values, _split_at_zero, largest_component
from deepcurrents.geometry.curves import write_curve_file
from deepcurrents.geometry.topology import border_loops, face_components, surface_topology


@dataclass(frozen=True)
class BodyPart:
    """A part of the partition: its name, the Anny bones it is made of (a regular expression), the part it hangs from
    (None for the root) and the name of the loop joining it to its parent."""

    name: str
    bones: str
    parent: str | None
    joint: str | None


def _limb(side: str) -> list[BodyPart]:
    s = re.escape(f".{side}")
    return [
        BodyPart(f"upperarm.{side}", rf"^upperarm0[12]{s}$", "torso", f"shoulder.{side}"),
        BodyPart(f"forearm.{side}", rf"^lowerarm0[12]{s}$", f"upperarm.{side}", f"elbow.{side}"),
        BodyPart(f"hand.{side}", rf"^(wrist|finger\d-\d|metacarpal\d){s}$", f"forearm.{side}", f"wrist.{side}"),
        BodyPart(f"thigh.{side}", rf"^upperleg0[12]{s}$", "torso", f"hip.{side}"),
        BodyPart(f"shin.{side}", rf"^lowerleg0[12]{s}$", f"thigh.{side}", f"knee.{side}"),
        BodyPart(f"foot.{side}", rf"^(foot|toe\d-\d){s}$", f"shin.{side}", f"ankle.{side}"),
    ]


# The 14 parts of a whole body (head and neck, torso, upper arms, forearms, hands, thighs, shins, feet)
BODY_PARTS: tuple[BodyPart, ...] = (
    BodyPart("torso", r"^(root|spine0\d|pelvis\.[LR]|clavicle\.[LR]|shoulder01\.[LR]|neck01)$", None, None),
    BodyPart("head", r"^(head|eye\.[LR]|neck02|neck03)$", "torso", "neck"),
    *_limb("L"), *_limb("R"),
)


def _depths(parts: Sequence[BodyPart]) -> dict[str, int]:
    by_name = {p.name: p for p in parts}
    depth: dict[str, int] = {}
    for p in parts:
        d, q = 0, p
        while q.parent is not None:
            d, q = d + 1, by_name[q.parent]
        depth[p.name] = d
    return depth


def subtree_shares(bone_weights: np.ndarray, bone_names: Sequence[str],
                   parts: Sequence[BodyPart] = BODY_PARTS) -> np.ndarray:
    """u_P for every part: the summed skinning weight of the bones of P and of every part below it.

    bone_weights (V, B), rows summing to one; bone_names (B,) → (V, len(parts)). DatasetError unless every bone
    belongs to exactly one part."""
    owner = np.full(len(bone_names), -1)
    for j, p in enumerate(parts):
        hit = np.array([re.match(p.bones, n) is not None for n in bone_names])
        if (hit & (owner >= 0)).any():
            raise DatasetError(f"Bone '{np.asarray(bone_names)[hit & (owner >= 0)][0]}' matches two body parts.")
        owner[hit] = j
    if (owner < 0).any():
        raise DatasetError(f"Bone '{np.asarray(bone_names)[owner < 0][0]}' belongs to no body part.")
    own = np.stack([bone_weights[:, owner == j].sum(1) for j in range(len(parts))], 1)
    index = {p.name: j for j, p in enumerate(parts)}
    depth = _depths(parts)
    shares = own.copy()
    for p in sorted(parts, key=lambda q: -depth[q.name]):  # leaves first: add each subtree to its parent
        if p.parent is not None:
            shares[:, index[p.parent]] += shares[:, index[p.name]]
    return shares


@dataclass(frozen=True)
class BodyPartition:
    """A partition of a mesh topology into parts with shared borders, as fixed affine combinations of the model's
    vertices.

    weights: (V', V) sparse, rows summing to one (the refined, closed body's vertices); faces: (F', 3) of the
    closed body; part: (F',) index into ``parts`` of each face; loops: each shared loop as (name, child part,
    parent part, vertex indices (M,) in the order the child's border runs)."""

    parts: tuple[BodyPart, ...]
    weights: scipy.sparse.csr_matrix
    faces: np.ndarray
    part: np.ndarray
    loops: tuple[tuple[str, str, str, np.ndarray], ...]

    def part_faces(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """(the body's vertex indices the part uses (V_p,), its faces (F_p, 3) indexing them)."""
        j = [p.name for p in self.parts].index(name)
        sub = self.faces[self.part == j]
        used = np.unique(sub)
        return used, np.searchsorted(used, sub)


def _face_of_edge(faces: np.ndarray) -> dict[tuple[int, int], int]:
    """The face each directed edge (a, b) belongs to, as its faces run. (F, 3) → {(a, b): face}."""
    directed = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]).tolist()
    return dict(zip(map(tuple, directed), np.tile(np.arange(len(faces)), 3).tolist(), strict=True))


def _reassign_islands(faces: np.ndarray, part: np.ndarray) -> np.ndarray:
    """Each part kept to its largest edge-connected piece: a smaller piece goes to the part it shares most edges
    with."""
    part = part.copy()
    pairs = trimesh.graph.face_adjacency(faces)
    for _ in range(10):
        same = part[pairs[:, 0]] == part[pairs[:, 1]]
        graph = scipy.sparse.coo_matrix((np.ones(same.sum()), (pairs[same, 0], pairs[same, 1])),
                                        shape=(len(faces),) * 2)
        _, piece = connected_components(graph, directed=False)
        moved = False
        for j in np.unique(part):
            pieces = np.unique(piece[part == j])
            if len(pieces) < 2:
                continue
            sizes = {q: int((piece == q).sum()) for q in pieces}
            largest = max(sizes, key=sizes.get)
            for q in pieces:
                if q == largest:
                    continue
                in_q = piece == q
                across = pairs[in_q[pairs[:, 0]] ^ in_q[pairs[:, 1]]]
                other = np.where(in_q[across[:, 0]], part[across[:, 1]], part[across[:, 0]])
                other = other[other != j]
                if len(other):
                    part[in_q] = np.bincount(other).argmax()
                    moved = True
        if not moved:
            break
    return part


def _cap_openings(weights: scipy.sparse.csr_matrix, faces: np.ndarray, part: np.ndarray
                  ) -> tuple[scipy.sparse.csr_matrix, np.ndarray, np.ndarray]:
    """Each border loop closed by a fan to its centroid (a new weights row, the mean of the loop's rows), the fan's
    faces given to the part of the faces along the loop."""
    rows, new_faces, new_part = [weights], [faces], [part]
    face_of_edge = _face_of_edge(faces)
    n = weights.shape[0]
    for loop in border_loops(faces):
        centre = n + len(rows) - 1
        rows.append(scipy.sparse.csr_matrix(weights[loop].mean(0)))
        owners = [part[face_of_edge[(a, b)]] for a, b in zip(loop.tolist(), np.roll(loop, -1).tolist(), strict=True)]
        new_faces.append(np.stack([np.roll(loop, -1), loop, np.full(len(loop), centre)], 1))
        new_part.append(np.full(len(loop), np.bincount(owners).argmax()))
    return (scipy.sparse.vstack(rows).tocsr(), np.concatenate(new_faces).astype(np.int64),
            np.concatenate(new_part))


def _shared_loops(faces: np.ndarray, part: np.ndarray, parts: Sequence[BodyPart]
                  ) -> tuple[tuple[str, str, str, np.ndarray], ...]:
    """Every border loop between a part and its parent, as the child's border runs; DatasetError for a border
    between parts that do not hang from each other, or a part whose loops are not its joint's."""
    names = [p.name for p in parts]
    face_of_edge = _face_of_edge(faces)
    loops = []
    for j, p in enumerate(parts):
        if p.parent is None:
            continue
        children = {q.name for q in parts if q.parent == p.name}
        to_parent = []
        for loop in border_loops(faces[part == j]):
            across = {names[part[face_of_edge[(b, a)]]]
                      for a, b in zip(loop.tolist(), np.roll(loop, -1).tolist(), strict=True)}
            if len(across) != 1 or not across <= children | {p.parent}:
                raise DatasetError(f"A border of {p.name} meets {', '.join(sorted(across))}, where {p.name} meets only "
                                   f"{', '.join(sorted(children | {p.parent}))}, each along one loop: the skinning "
                                   "shares do not separate these parts.")
            if across == {p.parent}:
                to_parent.append(loop)
        if len(to_parent) != 1:
            raise DatasetError(f"{p.name} meets {p.parent} along {len(to_parent)} loops where it should along one "
                               f"({p.joint}).")
        loops.append((p.joint, p.name, p.parent, to_parent[0]))
    return tuple(loops)


def partition_body(vertices: np.ndarray, faces: np.ndarray, bone_weights: np.ndarray, bone_names: Sequence[str],
                   hidden: np.ndarray | None = None, parts: Sequence[BodyPart] = BODY_PARTS,
                   snap: float = 0.2) -> BodyPartition:
    """The partition of a closed body mesh topology into ``parts`` along level sets 1/2 of the subtree shares (module
    docstring).

    vertices (V, 3): a reference body (chooses the shorter diagonals); faces (F, 3); bone_weights (V, B); hidden
    (F,) bool: faces to leave out (their openings are capped); snap: as ``level_set_cut``."""
    vertices, faces = np.asarray(vertices, np.float64), np.asarray(faces, np.int64)
    shares = subtree_shares(bone_weights, bone_names, parts)
    depth = _depths(parts)
    weights = scipy.sparse.identity(len(vertices), format="csr")
    hidden = np.zeros(len(faces), bool) if hidden is None else np.asarray(hidden, bool)
    inside = np.zeros((len(faces), len(parts)), bool)
    for j, p in enumerate(parts):
        if p.parent is None:
            continue
        at = weights @ vertices
        values = weights @ shares[:, j] - 0.5
        snapped = _snap_values(faces, values, snap)
        for _ in range(10):  # a snapped saddle vertex would pinch a side: such vertices keep their own value
            split_w, split_f, positive, origin = _split_at_zero(at, faces, snapped, values, None)
            pinched = np.concatenate([_pinched_vertices(split_f[positive]), _pinched_vertices(split_f[~positive])])
            pinched = pinched[pinched < len(at)]
            pinched = pinched[(snapped[pinched] == 0) & (values[pinched] != 0)]
            if len(pinched) == 0:
                break
            snapped[pinched] = values[pinched]
        weights = (split_w @ weights).tocsr()
        faces, hidden = split_f, hidden[origin]
        inside = inside[origin]
        inside[:, j] = positive
    # each face to the deepest part whose cut it lies inside (the torso where none)
    order = np.array([depth[p.name] for p in parts])
    part = np.where(inside.any(1), np.argmax(np.where(inside, order + 1, 0), axis=1),
                    [i for i, p in enumerate(parts) if p.parent is None][0])
    # the visible body: hidden faces and the pieces they leave (the eyeballs) dropped
    faces, part = faces[~hidden], part[~hidden]
    keep = largest_component(faces)
    faces, part = faces[keep], part[keep]
    used = np.unique(faces)
    weights, faces = weights[used], np.searchsorted(used, faces)
    part = _reassign_islands(faces, part)
    weights, faces, part = _cap_openings(weights, faces, part)
    topology = surface_topology(faces)
    if topology.border_loops or topology.components != 1 or not topology.manifold:
        raise DatasetError(f"The capped body is not one closed manifold surface ({topology.describe()}).")
    return BodyPartition(tuple(parts), weights, faces, part, _shared_loops(faces, part, parts))


def anny_body_partition(num: int, seed: int = 0, pose_degrees: float = 6.0, model=None
                        ) -> tuple[BodyPartition, list[np.ndarray]]:
    """``num`` Anny bodies (``human_parts_builder.anny_bodies``) and the partition of their topology (made on the
    first). → (partition, bodies (V, 3) each)."""
    from deepcurrents.data.human_parts_builder import anny_bodies, anny_model, anny_skinning

    model = model if model is not None else anny_model()
    faces = model.get_triangular_faces().cpu().numpy().astype(np.int64)
    bone_weights, hidden = anny_skinning(model)
    bodies = anny_bodies(model, num, seed, pose_degrees)
    return partition_body(bodies[0], faces, bone_weights, list(model.bone_labels), hidden), bodies


def write_body(partition: BodyPartition, body: np.ndarray, folder: str | Path, meta: dict | None = None) -> Path:
    """One body's files (module docstring) into ``folder``; body (V, 3) the model's vertices of this body."""
    verts = np.asarray(partition.weights @ np.asarray(body, np.float64))
    return write_body_files(folder, verts, partition.faces, partition.part, [p.name for p in partition.parts],
                            {p.name: p.parent for p in partition.parts}, partition.loops, meta)


def write_body_files(folder: str | Path, verts: np.ndarray, faces: np.ndarray, face_part: np.ndarray,
                     names: Sequence[str], parents: dict[str, str | None],
                     loops: Sequence[tuple[str, str, str, np.ndarray]], meta: dict | None = None) -> Path:
    """A body folder from its vertices (V, 3), faces (F, 3), the part of each face (F,) (indices into ``names``),
    each part's parent and the shared loops (name, child, parent, vertex indices)."""
    folder = Path(folder)
    (folder / "parts").mkdir(parents=True, exist_ok=True)
    (folder / "loops").mkdir(exist_ok=True)
    trimesh.Trimesh(verts, faces, process=False).export(folder / "body.ply")
    parts_info = {}
    for j, name in enumerate(names):
        sub = faces[face_part == j]
        used = np.unique(sub)
        trimesh.Trimesh(verts[used], np.searchsorted(used, sub), process=False).export(folder / "parts" / f"{name}.ply")
        parts_info[name] = {"file": f"parts/{name}.ply", "parent": parents[name], "body_vertices": used.tolist(),
                            "loops": [lp for lp, child, parent, _ in loops if name in (child, parent)]}
    loops_info = []
    for name, child, parent, idx in loops:
        loop = verts[idx]
        lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in loop] + ["l " + " ".join(str(i + 1) for i in range(len(loop)))
                                                               + " 1"]
        (folder / "loops" / f"{name}.obj").write_text("\n".join(lines) + "\n")
        loops_info.append({"name": name, "parts": [child, parent], "file": f"loops/{name}.obj",
                           "body_vertices": np.asarray(idx).tolist(), "vertices": loop.tolist()})
    info = {"parts": parts_info, "loops": loops_info, "face_part": np.asarray(face_part).tolist(),
            "vertices": int(len(verts)), "faces": int(len(faces)), **(meta or {})}
    (folder / "loops.json").write_text(json.dumps(info))
    return folder


@dataclass(frozen=True)
class StitchedBody:
    """A body folder as ``write_body`` wrote it: the folder, the closed body (V, 3)/(F, 3), the part of each face
    (F,) (indices into ``parts``' order), each part's file, parent, loops and body vertices, and each shared loop
    (name, (child, parent), vertices (M, 3) float64, their indices into the body (M,))."""

    folder: Path
    body_vertices: np.ndarray
    body_faces: np.ndarray
    face_part: np.ndarray
    parts: dict[str, dict]
    loops: list[tuple[str, tuple[str, str], np.ndarray, np.ndarray]]

    def part_file(self, name: str) -> Path:
        return self.folder / self.parts[name]["file"]


def read_body(folder: str | Path) -> StitchedBody:
    """A body folder (``loops.json`` is JSON, read without unpickling anything); DatasetError naming the file and
    what is wrong when it is missing or malformed."""
    folder = Path(folder)
    info_path = folder / "loops.json"
    if not info_path.is_file():
        hint = "run `make data` (or `deepcurrents-make-dataset --whole-bodies N`) to build it"
        raise DatasetError(f"Body folder '{folder}' has no loops.json; {hint}.")
    try:
        info = json.loads(info_path.read_text())
        parts = {str(k): dict(v) for k, v in info["parts"].items()}
        loops = [(str(lp["name"]), (str(lp["parts"][0]), str(lp["parts"][1])), np.asarray(lp["vertices"], np.float64),
                  np.asarray(lp["body_vertices"], np.int64)) for lp in info["loops"]]
        face_part = np.asarray(info["face_part"], np.int64)
    except (json.JSONDecodeError, KeyError, TypeError, ValueError, IndexError) as err:
        raise DatasetError(f"'{info_path}' is not a body's loops.json ({type(err).__name__}: {err}).") from None
    for name, pair, verts, _ in loops:
        if verts.ndim != 2 or verts.shape[1] != 3 or len(verts) < 3 or not np.isfinite(verts).all():
            raise DatasetError(f"'{info_path}': loop {name} must be at least 3 finite points (x, y, z).")
        if not set(pair) <= set(parts):
            raise DatasetError(f"'{info_path}': loop {name} joins {pair[0]} and {pair[1]}, which are not both parts.")
    for name, part in parts.items():
        if not (folder / str(part.get("file", ""))).is_file():
            raise DatasetError(f"Body folder '{folder}': the mesh of part {name} ({part.get('file')}) is missing.")
    body_path = folder / "body.ply"
    if not body_path.is_file():
        raise DatasetError(f"Body folder '{folder}' has no body.ply.")
    body = trimesh.load(body_path, process=False, force="mesh")
    if len(face_part) != len(body.faces):
        raise DatasetError(f"'{info_path}' gives the parts of {len(face_part)} faces; body.ply has {len(body.faces)}.")
    return StitchedBody(folder, np.asarray(body.vertices, np.float64), np.asarray(body.faces, np.int64), face_part,
                        parts, loops)


# ---------------------------------------------------------------------- families of two parts joined at one loop

JOINED_HALF_LENGTH = 0.45  # the parent's length from the joint in the joined frame (hand and forearm fit [-0.5, 0.5]³)


def joint_frame(joint: np.ndarray, far: np.ndarray, side: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """The frame in which two parts joined at ``joint`` (M, 3) are a family's shapes: the joint's centroid at the
    origin, +z towards the centroid of the parent's other loop ``far`` (P, 3) at ``JOINED_HALF_LENGTH``, +x along the
    joint's longest in-plane direction, turned to agree with ``side`` (3,), the same world direction for every body.
    → (scale, rotation R (3, 3), origin (3,)): frame = R (world − origin) · scale."""
    origin = joint.mean(0)
    axis = far.mean(0) - origin
    length = float(np.linalg.norm(axis))
    z = axis / length
    flat = (joint - origin) - np.outer((joint - origin) @ z, z)
    x = np.linalg.svd(flat, full_matrices=False)[2][0]
    x = x - (x @ z) * z
    x = x / np.linalg.norm(x) * (1.0 if x @ side >= 0 else -1.0)
    return JOINED_HALF_LENGTH / length, np.stack([x, np.cross(z, x), z]), origin


def write_joined_families(partition: BodyPartition, bodies: Sequence[np.ndarray], root: str | Path,
                          joint: str = "wrist.L", meta: dict | None = None) -> Path:
    """Two families whose shapes share a loop: for each body, the two parts that ``joint`` joins (the hand and the
    forearm at the wrist) in the body's ``joint_frame``, so a child family and a parent family can be trained apart,
    generated for one (edited) joint and stitched there (``deepcurrents-generate neighbour_ckpt=…``).

    Writes ``<root>/<joint>/<child>/NNN.ply`` and ``<parent>/NNN.ply`` (the families' meshes),
    ``curves/NNN/<part>.obj`` (each part's Γ in the frame, each loop as that part's border runs, for ``generate
    curve=``), ``curves/NNN/<joint>.obj`` and ``frames.json`` (each body's scale, rotation and origin: frame =
    R (body − origin) · scale). → the joint's folder."""
    loops = {name: (child, parent, idx) for name, child, parent, idx in partition.loops}
    if joint not in loops:
        raise DatasetError(f"joint='{joint}' is not a loop of the partition ({', '.join(sorted(loops))}).")
    child, parent, joint_idx = loops[joint]
    far = [idx for name, (c, p, idx) in loops.items() if name != joint and parent in (c, p)]
    if len(far) != 1:
        raise DatasetError(f"joint='{joint}': its parent {parent} must have exactly one other loop (it has "
                           f"{len(far)}).")
    folder = Path(root) / joint
    frames = {}
    reference = None
    for i, body in enumerate(bodies):
        verts = np.asarray(partition.weights @ np.asarray(body, np.float64))
        if reference is None:  # the first body's in-plane direction fixes x's sign for all
            reference = joint_frame(verts[joint_idx], verts[far[0]], np.ones(3))[1][0]
        scale, rotation, origin = joint_frame(verts[joint_idx], verts[far[0]], reference)
        framed = (verts - origin) @ rotation.T * scale
        for part in (child, parent):
            used, faces = partition.part_faces(part)
            (folder / part).mkdir(parents=True, exist_ok=True)
            trimesh.Trimesh(framed[used], faces, process=False).export(folder / part / f"{i:03d}.ply")
        curves = folder / "curves" / f"{i:03d}"
        curves.mkdir(parents=True, exist_ok=True)
        for part in (child, parent):  # each loop as the part's own border runs (a parent's against its child's)
            own = [idx if c == part else idx[::-1] for name, (c, p, idx) in loops.items() if part in (c, p)]
            write_curve_file(curves / f"{part}.obj", [framed[idx] for idx in own])
        write_curve_file(curves / f"{joint}.obj", [framed[joint_idx]])
        frames[f"{i:03d}"] = {"scale": scale, "rotation": rotation.tolist(), "origin": origin.tolist()}
    info = {"joint": joint, "child": child, "parent": parent, "frames": frames, **(meta or {})}
    (folder / "frames.json").write_text(json.dumps(info, indent=1))
    return folder


# ---------------------------------------------------------------------------------------------- FAUST

# FAUST's segmentation labels of the body parts (the benchmark's eight; one label for both sides of a limb)
FAUST_BODY_LABELS = {"head": 1, "hand": 2, "forearm": 3, "upperarm": 4, "torso": 5, "thigh": 6, "shin": 7, "foot": 8}


def faust_face_parts(vertices: np.ndarray, faces: np.ndarray, labels: np.ndarray,
                     parts: Sequence[BodyPart] = BODY_PARTS) -> np.ndarray:
    """Each face's part (index into ``parts``) from FAUST's eight labels: a limb's faces go to the side (.L: towards
    +x, as Anny's) of the line between the two hands' pieces, through the torso's centroid. vertices (V, 3), faces
    (F, 3), labels (F,) → (F,); DatasetError for a label that is not one of the eight, or hands not in two pieces."""
    unknown = sorted(set(np.unique(labels).tolist()) - set(FAUST_BODY_LABELS.values()))
    if unknown:
        raise DatasetError(f"FAUST label {unknown[0]} is not one of the segmentation's eight (1 head, 2 hand, "
                           "3 forearm, 4 upper arm, 5 torso, 6 thigh, 7 shin, 8 foot).")
    centres = vertices[faces].mean(1)
    hand_faces = np.flatnonzero(labels == FAUST_BODY_LABELS["hand"])
    piece = face_components(faces[hand_faces], len(vertices))
    sizes = np.bincount(piece)
    if (sizes > 0).sum() < 2:
        raise DatasetError("FAUST's hand label must lie in two pieces (one hand on each side).")
    a, b = np.argsort(sizes)[-2:]
    lateral = centres[hand_faces[piece == a]].mean(0) - centres[hand_faces[piece == b]].mean(0)
    lateral *= 1.0 if lateral[0] >= 0 else -1.0
    side = np.where((centres - centres[labels == FAUST_BODY_LABELS["torso"]].mean(0)) @ lateral >= 0, "L", "R")
    index = {p.name: j for j, p in enumerate(parts)}
    out = np.empty(len(faces), np.int64)
    for name, label in FAUST_BODY_LABELS.items():
        hit = labels == label
        if name in index:
            out[hit] = index[name]
        else:
            for s in ("L", "R"):
                out[hit & (side == s)] = index[f"{name}.{s}"]
    return out


def faust_body_partition(root: str | Path) -> tuple[BodyPartition, list[np.ndarray]]:
    """FAUST's registrations (``human_parts_builder.load_faust``: one closed topology) cut into the 14 parts: each
    part's faces (``faust_face_parts``) smoothed onto the vertices as the single FAUST parts are
    (``smooth_label_field``) stand in for the skinning weights, so each loop is the level set 1/2 of a subtree's
    smoothed share, shared by both sides as for Anny. → (partition, bodies (V, 3) each)."""
    from deepcurrents.data.human_parts_builder import load_faust, smooth_label_field

    bodies, faces, labels = load_faust(root)
    face_part = faust_face_parts(bodies[0], faces, labels)
    weights = np.stack([smooth_label_field(faces, face_part == j, len(bodies[0])) for j in range(len(BODY_PARTS))], 1)
    parts = tuple(BodyPart(p.name, rf"^{re.escape(p.name)}$", p.parent, p.joint) for p in BODY_PARTS)
    return partition_body(bodies[0], faces, weights, [p.name for p in parts], parts=parts), bodies
