"""Whole bodies cut into parts with shared loops: a synthetic three-part body with skinning shares linear in z (where
the cuts must lie is known exactly), then Anny's 14 parts written and read back."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh
from conftest import CHAIN, synthetic_body

from deepcurrents.cli.make_dataset import main
from deepcurrents.data.body_partition import (
    BodyPart,
    partition_body,
    read_body,
    subtree_shares,
    write_body,
)
from deepcurrents.data.human_parts import DatasetError
from deepcurrents.geometry.topology import border_loops, surface_topology


def test_subtree_shares_add_the_parts_below():
    verts, _, weights, names, _ = synthetic_body()
    shares = subtree_shares(weights, names, CHAIN)
    np.testing.assert_allclose(shares[:, 0], 1.0)
    np.testing.assert_allclose(shares[:, 1], weights[:, 1] + weights[:, 2])
    np.testing.assert_allclose(shares[:, 2], weights[:, 2])
    with pytest.raises(DatasetError, match="Bone 'extra' belongs to no body part"):
        subtree_shares(np.c_[weights, np.zeros(len(weights))], [*names, "extra"], CHAIN)
    with pytest.raises(DatasetError, match="matches two body parts"):
        subtree_shares(weights, names, (*CHAIN, BodyPart("again", r"^hand$", "limb", "x")))


def test_partition_cuts_on_the_level_sets_and_shares_each_loop():
    verts, faces, weights, names, _ = synthetic_body()
    part = partition_body(verts, faces, weights, names, parts=CHAIN, snap=0.0)
    at = np.asarray(part.weights @ verts)
    np.testing.assert_allclose(part.weights.sum(1), 1.0)
    # every face in one part; the body closed; each part the expected piece
    assert surface_topology(part.faces).describe() == "a connected surface (genus 0, 0 border loops, χ = 2)"
    kinds = {p.name: surface_topology(part.part_faces(p.name)[1]).describe() for p in CHAIN}
    assert kinds == {"torso": "a disk (genus 0, 1 border loop, χ = 1)",
                     "limb": "an annulus (genus 0, 2 border loops, χ = 0)",
                     "hand": "a disk (genus 0, 1 border loop, χ = 1)"}
    # the loops lie on the level sets z = 0 and z = 1 (the shares are linear there), and the area is the body's
    loops = {name: (child, parent, idx) for name, child, parent, idx in part.loops}
    np.testing.assert_allclose(at[loops["shoulder"][2], 2], 0.0, atol=1e-12)
    np.testing.assert_allclose(at[loops["wrist"][2], 2], 1.0, atol=1e-12)
    assert loops["shoulder"][:2] == ("limb", "torso") and loops["wrist"][:2] == ("hand", "limb")
    assert trimesh.Trimesh(at, part.faces).area == pytest.approx(trimesh.Trimesh(verts, faces).area, rel=1e-12)
    # the child runs the loop one way, the parent the other: as the child's border, reversed as the parent's
    for name, (_, parent, idx) in loops.items():
        used, sub = part.part_faces(parent)
        parent_loops = [used[lp] for lp in border_loops(sub)]
        rolled = [np.roll(lp[::-1], -int(np.flatnonzero(lp[::-1] == idx[0])[0]))
                  for lp in parent_loops if idx[0] in lp]
        assert len(rolled) == 1 and np.array_equal(rolled[0], idx), name


def test_hidden_faces_are_left_out_and_their_opening_capped():
    verts, faces, weights, names, hidden = synthetic_body(hidden_cap=True)
    part = partition_body(verts, faces, weights, names, hidden=hidden, parts=CHAIN)
    at = np.asarray(part.weights @ verts)
    assert surface_topology(part.faces).border_loops == 0
    # the cap is a fan to the opening's centroid, which lies on the hidden region's rim plane
    assert at[:, 2].min() > -2.0 + 1e-3
    torso = part.part_faces("torso")[1]
    assert surface_topology(torso).border_loops == 1  # the cap belongs to the torso: its only border is the loop


def test_write_and_read_a_body(tmp_path):
    verts, faces, weights, names, _ = synthetic_body()
    part = partition_body(verts, faces, weights, names, parts=CHAIN)
    folder = write_body(part, verts, tmp_path / "000")
    body = read_body(folder)
    assert set(body.parts) == {"torso", "limb", "hand"} and [lp[0] for lp in body.loops] == ["shoulder", "wrist"]
    for _, (child, parent), loop, _ in body.loops:
        for p in (child, parent):  # each part's file ends exactly on the loop (float32 files: to 1e-6)
            mesh = trimesh.load(body.part_file(p), process=False)
            ends = [np.asarray(mesh.vertices)[lp] for lp in border_loops(np.asarray(mesh.faces))]
            assert any(len(e) == len(loop) and np.abs(np.sort(e, 0) - np.sort(loop, 0)).max() < 1e-6 for e in ends)
    (folder / "loops.json").write_text("{not json")
    with pytest.raises(DatasetError, match="is not a body's loops.json"):
        read_body(folder)
    with pytest.raises(DatasetError, match="has no loops.json; run `make data`"):
        read_body(tmp_path / "nothing")


def test_anny_whole_bodies_from_the_command_line(tmp_path):
    main(["--source", "anny", "--whole-bodies", "1", "--categories", "--out", str(tmp_path)])
    body = read_body(tmp_path / "anny" / "bodies" / "000")
    assert len(body.parts) == 14 and len(body.loops) == 13
    assert surface_topology(body.body_faces).describe() == "a connected surface (genus 0, 0 border loops, χ = 2)"
    for name, info in body.parts.items():
        mesh = trimesh.load(body.part_file(name), process=False)
        loops = len(border_loops(np.asarray(mesh.faces)))
        assert loops == len(info["loops"]), name
    with pytest.raises(SystemExit):
        main(["--source", "faust", "--whole-bodies", "1", "--faust-root", str(tmp_path), "--out", str(tmp_path)])


def test_anny_joined_parts_from_the_command_line_are_two_families(tmp_path):
    from deepcurrents.data.family import family_files, load_family

    main(["--source", "anny", "--joined-parts", "2", "--joint", "elbow.R", "--categories", "--out", str(tmp_path)])
    folder = tmp_path / "anny" / "joined" / "elbow.R"
    forearms = load_family(family_files(folder / "forearm.R"))
    upperarms = load_family(family_files(folder / "upperarm.R"))
    assert len(forearms) == 2 and [len(m.loops) for m in forearms] == [2, 2]
    assert [len(m.loops) for m in upperarms] == [2, 2]
    assert (folder / "curves" / "001" / "forearm.R.obj").is_file()
    with pytest.raises(SystemExit):
        main(["--source", "anny", "--joined-parts", "1", "--joint", "hip.L", "--out", str(tmp_path)])


def test_moving_a_loop_carries_the_parts_below_and_deforms_the_one_above(tmp_path):
    from deepcurrents.data.body_edit import LoopMove, move_loop, parts_below

    verts, faces, weights, names, _ = synthetic_body()
    body = read_body(write_body(partition_body(verts, faces, weights, names, parts=CHAIN), verts, tmp_path / "b"))
    assert parts_below(body, "limb") == ["limb", "hand"]
    loops = {name: (pair, idx) for name, pair, _, idx in body.loops}
    wrist, shoulder = loops["wrist"][1], loops["shoulder"][1]
    move = LoopMove(rotate=30.0, axis=(1.0, 0.0, 0.0))
    # carry: the hand and the limb turn rigidly about the wrist loop's centroid, the torso deforms; the shoulder is
    # the limb's, so it turns too
    moved, refit, rigid = move_loop(body, "shoulder", move, carry=True)
    assert refit == ["torso"] and rigid == ["limb", "hand"]
    centre = body.body_vertices[shoulder].mean(0)
    c, s = np.cos(np.pi / 6), np.sin(np.pi / 6)
    rotation = np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    limb = np.asarray(body.parts["limb"]["body_vertices"] + body.parts["hand"]["body_vertices"])
    np.testing.assert_allclose(moved[limb], centre + (body.body_vertices[limb] - centre) @ rotation.T, atol=1e-12)
    # the torso follows near the moved loop and stays put beyond 0.75 of its diameter (here 1.5) from it
    torso = np.asarray(body.parts["torso"]["body_vertices"])
    shift = np.linalg.norm(moved[torso] - body.body_vertices[torso], axis=1)
    z = body.body_vertices[torso, 2]
    assert shift[z < -1.8].max() == 0.0 and shift[z > -0.3].mean() > 0.1
    assert np.isfinite(moved).all() and shift.max() < 0.6
    # no carry: the loop alone moves (scaled), both parts it joins deform, the other loop stays where it was
    moved, refit, rigid = move_loop(body, "wrist", LoopMove(scale=0.5), carry=False)
    assert refit == ["hand", "limb"] and rigid == []
    ring = body.body_vertices[wrist]
    np.testing.assert_allclose(moved[wrist], ring.mean(0) + 0.5 * (ring - ring.mean(0)), atol=1e-12)
    np.testing.assert_array_equal(moved[shoulder], body.body_vertices[shoulder])
    np.testing.assert_array_equal(moved[torso], body.body_vertices[torso])
    with pytest.raises(DatasetError, match="has no loop 'elbow'; its loops are shoulder, wrist"):
        move_loop(body, "elbow", move)


def test_joined_families_are_two_parts_in_each_bodys_joint_frame_sharing_the_joint_loop(tmp_path):
    """write_joined_families on the synthetic chain: the hand and the limb of each body in the frame of its wrist
    (centroid at the origin, the shoulder's centroid at JOINED_HALF_LENGTH along +z), the wrist in both parts' curve
    files as the same points, each part's border its curve; a body moved rigidly and scaled gives the same files."""
    from scipy.spatial.transform import Rotation

    from deepcurrents.data.body_partition import JOINED_HALF_LENGTH, write_joined_families
    from deepcurrents.geometry.curves import load_boundary

    verts, faces, weights, names, _ = synthetic_body()
    verts = verts * [1.3, 1.0, 1.0]  # an elliptic wrist: its longest in-plane direction is x
    partition = partition_body(verts, faces, weights, names, parts=CHAIN)
    moved = 0.7 * verts @ Rotation.from_rotvec([0.1, -0.05, 0.08]).as_matrix().T + [0.3, -0.2, 1.0]
    folder = write_joined_families(partition, [verts, moved], tmp_path, joint="wrist")
    assert json.loads((folder / "frames.json").read_text())["child"] == "hand"
    for i in ("000", "001"):
        wrist = load_boundary(str(folder / "curves" / i / "wrist.obj")).loops[0]
        np.testing.assert_allclose(wrist.mean(0), 0.0, atol=1e-6)
        limb_loops = load_boundary(str(folder / "curves" / i / "limb.obj")).loops
        shoulder = next(lp for lp in limb_loops if lp.mean(0)[2] > 0.1)
        np.testing.assert_allclose(shoulder.mean(0), [0, 0, JOINED_HALF_LENGTH], atol=1e-6)
        assert any(np.array_equal(lp[::-1], wrist) for lp in limb_loops)  # the limb's border runs it the other way
        np.testing.assert_array_equal(load_boundary(str(folder / "curves" / i / "hand.obj")).loops[0], wrist)
        hand = trimesh.load(folder / "hand" / f"{i}.ply", process=False)
        border = border_loops(np.asarray(hand.faces))
        assert len(border) == 1
        np.testing.assert_allclose(np.sort(hand.vertices[border[0]], 0), np.sort(wrist, 0), atol=1e-8)
    for part in ("hand", "limb"):
        a, b = (trimesh.load(folder / part / f"{i}.ply", process=False) for i in ("000", "001"))
        np.testing.assert_allclose(a.vertices, b.vertices, atol=1e-9)
    with pytest.raises(DatasetError, match=r"^joint='shoulder': its parent torso must have exactly one other loop"):
        write_joined_families(partition, [verts], tmp_path, joint="shoulder")


def test_a_faust_layout_is_cut_into_the_same_parts_along_its_eight_labels(tmp_path):
    """FAUST's segmentation (eight labels, no sides) stands in for the skinning: a FAUST-style folder made from two
    Anny bodies (their closed meshes, their parts' faces merged to the eight labels) is cut into the 14 parts and 13
    shared loops; each face lands in the part it came from, away from the cuts (the borders move by the smoothing)."""
    from deepcurrents.data.body_partition import FAUST_BODY_LABELS, anny_body_partition, faust_body_partition

    partition, bodies = anny_body_partition(2, seed=3)
    names = [p.name for p in partition.parts]
    labels = np.array([FAUST_BODY_LABELS[n.split(".")[0]] for n in names])[partition.part]
    (tmp_path / "meshes" / "train" / "faust").mkdir(parents=True)
    (tmp_path / "segs" / "train" / "faust").mkdir(parents=True)
    for i, body in enumerate(bodies):
        verts = np.asarray(partition.weights @ body)
        trimesh.Trimesh(verts, partition.faces, process=False).export(tmp_path / "meshes/train/faust" / f"tr_{i}.ply")
    np.savetxt(tmp_path / "segs/train/faust/faust_corrected.txt", labels, fmt="%d")
    faust, faust_bodies = faust_body_partition(tmp_path)
    assert [p.name for p in faust.parts] == names and len(faust.loops) == 13 and len(faust_bodies) == 2
    assert surface_topology(faust.faces).describe() == "a connected surface (genus 0, 0 border loops, χ = 2)"
    # each new face's part against the part of the original face under its centroid
    verts = np.asarray(partition.weights @ bodies[0])
    new = np.asarray(faust.weights @ faust_bodies[0])[faust.faces].mean(1)
    from scipy.spatial import cKDTree

    _, nearest = cKDTree(verts[partition.faces].mean(1)).query(new)
    agree = faust.part == partition.part[nearest]
    assert agree.mean() > 0.9
    for j, name in enumerate(names):  # both sides found: every part keeps most of its own faces
        assert agree[partition.part[nearest] == j].mean() > 0.6, name
    np.savetxt(tmp_path / "segs/train/faust/faust_corrected.txt", np.where(labels == 5, 11, labels), fmt="%d")
    with pytest.raises(DatasetError, match=r"^FAUST label 11 is not one of the segmentation's eight"):
        faust_body_partition(tmp_path)
