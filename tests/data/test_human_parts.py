"""Human-part datasets: the Anny generator on two bodies and the FAUST loader on a fixture in the
segmentation benchmark's layout that the test writes itself."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from deepcurrents.cli.make_dataset import main
from deepcurrents.data.human_parts import CATEGORIES, DatasetError, dataset_path
from deepcurrents.data.human_parts_builder import (
    PartCut,
    anny_model,
    anny_parts,
    faust_parts,
    kabsch_rotation,
    level_set_cut,
    select_faces,
    smooth_label_field,
    write_parts,
)
from deepcurrents.data.targets import mesh_boundary_loops


def check_parts(parts: dict, count: int) -> None:
    """Every category: ``count`` meshes of one topology, with boundary, inside [-0.5, 0.5]^3 (one of them
    touching it), centred, and rotated onto the first (Kabsch finds no further rotation)."""
    for name, (meshes, faces, scale) in parts.items():
        assert len(meshes) == count and scale > 0, name
        assert len(mesh_boundary_loops(meshes[0], faces)) >= 1, name
        extent = max(float(np.abs(m).max()) for m in meshes)
        assert extent == pytest.approx(0.5), name
        for m in meshes:
            np.testing.assert_allclose(m.mean(0), 0.0, atol=1e-12)
            np.testing.assert_allclose(kabsch_rotation(m, meshes[0]), np.eye(3), atol=1e-9)
        # one connected component
        labels = trimesh.graph.connected_component_labels(trimesh.Trimesh(meshes[0], faces).face_adjacency,
                                                          node_count=len(faces))
        assert labels.max() == 0, name


def test_kabsch_recovers_a_rotation():
    rng = np.random.default_rng(0)
    pts = rng.standard_normal((50, 3))
    pts -= pts.mean(0)
    q, _ = np.linalg.qr(rng.standard_normal((3, 3)))
    rot = q * np.sign(np.linalg.det(q))
    np.testing.assert_allclose(kabsch_rotation(pts, pts @ rot.T), rot, atol=1e-12)


def test_anny_generator_on_two_bodies(tmp_path):
    model = anny_model()
    parts = anny_parts(2, seed=3, model=model)
    assert set(parts) == set(CATEGORIES)
    check_parts(parts, 2)
    # the hand: one wrist loop; the torso: neck, two arms, two legs
    assert len(mesh_boundary_loops(parts["hands"][0][0], parts["hands"][1])) == 1
    assert len(mesh_boundary_loops(parts["torsos"][0][0], parts["torsos"][1])) == 5
    # the two bodies differ (random phenotype and pose)
    assert np.abs(parts["hands"][0][0] - parts["hands"][0][1]).max() > 0.01
    files = write_parts(parts, tmp_path, "anny")
    assert len(files) == 12 and dataset_path(tmp_path, "anny", "feet", 1).name == "001.ply"
    mesh = trimesh.load(dataset_path(tmp_path, "anny", "hands", 0), process=False)
    np.testing.assert_allclose(mesh.vertices, parts["hands"][0][0], atol=1e-6)


def write_faust_fixture(root, bodies: int = 3):
    """A tiny FAUST-like benchmark: bodies of one topology made of six labelled open pieces (two of
    them, like FAUST's two hands, under one label), plus ``faust_corrected.txt``."""
    mesh_dir = root / "meshes" / "train" / "faust"
    seg_dir = root / "segs" / "train" / "faust"
    mesh_dir.mkdir(parents=True)
    seg_dir.mkdir(parents=True)
    pieces, labels = [], []
    grid = trimesh.creation.box().subdivide()
    keep = grid.face_normals[:, 2] < 0.99  # an open box: its top removed
    piece = trimesh.Trimesh(grid.vertices, grid.faces[keep])
    piece.remove_unreferenced_vertices()
    for k, label in enumerate([1, 2, 2, 3, 4, 5, 8]):
        scale = 0.5 if (label == 2 and k == 2) else 1.0  # the second "hand" is smaller
        pieces.append(trimesh.Trimesh(piece.vertices * scale + [3.0 * k, 0, 0], piece.faces))
        labels += [label] * len(piece.faces)
    body = trimesh.util.concatenate(pieces)
    rng = np.random.default_rng(0)
    for i in range(bodies):
        q, _ = np.linalg.qr(rng.standard_normal((3, 3)))
        q *= np.sign(np.linalg.det(q))
        verts = body.vertices @ q.T * (1 + 0.1 * i) + rng.standard_normal(3)
        trimesh.Trimesh(verts, body.faces, process=False).export(mesh_dir / f"tr_reg_{i:03d}.ply")
    np.savetxt(seg_dir / "faust_corrected.txt", np.array(labels), fmt="%d")
    return len(piece.faces)


def test_faust_loader_on_a_fixture(tmp_path):
    piece_faces = write_faust_fixture(tmp_path)
    parts = faust_parts(tmp_path)
    check_parts(parts, 3)
    # each category is its piece; the hands keep the larger of the two
    assert all(len(faces) == piece_faces for _, faces, _ in parts.values())
    # rigid alignment: the rotated copies coincide up to the per-body scale, which one category scale keeps
    hands = parts["hands"][0]
    ratio = np.linalg.norm(hands[2], axis=1).sum() / np.linalg.norm(hands[0], axis=1).sum()
    np.testing.assert_allclose(hands[2], hands[0] * ratio, atol=1e-6)  # PLY stores float32
    assert ratio == pytest.approx(1.2, rel=1e-6)
    main(["--source", "faust", "--faust-root", str(tmp_path), "--out", str(tmp_path / "out")])
    assert len(list((tmp_path / "out" / "faust" / "torsos").glob("*.ply"))) == 3


def test_dataset_errors_say_what_to_do(tmp_path, capsys):
    with pytest.raises(DatasetError, match="make data"):
        dataset_path(tmp_path, "anny", "hands", 0)
    with pytest.raises(DatasetError, match="is not a directory"):
        faust_parts(tmp_path)
    with pytest.raises(SystemExit) as err:
        main(["--source", "faust", "--out", str(tmp_path)])
    assert err.value.code == 2 and "--faust-root is required" in capsys.readouterr().err


# ---------------------------------------------------------------------------------------------- smooth borders

def tube(rings: np.ndarray, sides: int = 24, radius: float = 0.3, twist: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """An open prism tube: ``sides`` vertices on each ring at heights ``rings``, each ring turned by
    ``twist`` × its index, every quad split in two, faces outward. → (vertices (R·S, 3), faces (F, 3))."""
    ang = 2 * np.pi * np.arange(sides) / sides
    verts = np.concatenate([np.c_[radius * np.cos(ang + twist * i), radius * np.sin(ang + twist * i),
                                  np.full(sides, z)] for i, z in enumerate(rings)])
    faces = []
    for i in range(len(rings) - 1):
        for j in range(sides):
            a, b = i * sides + j, i * sides + (j + 1) % sides
            c, d = a + sides, b + sides
            faces += [[a, b, d], [a, d, c]]
    return verts, np.array(faces, dtype=np.int64)


def loop_stats(vertices: np.ndarray, faces: np.ndarray) -> tuple[list[np.ndarray], np.ndarray]:
    """(border loops, how many border edges meet at each border vertex)."""
    edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    uniq, count = np.unique(edges, axis=0, return_counts=True)
    assert count.max() <= 2  # no edge shared by three triangles
    _, per_vertex = np.unique(uniq[count == 1].ravel(), return_counts=True)
    return mesh_boundary_loops(vertices, faces), per_vertex


def smallest_angle(vertices: np.ndarray, faces: np.ndarray) -> float:
    tri = vertices[faces]
    best = 180.0
    for k in range(3):
        a, b = tri[:, (k + 1) % 3] - tri[:, k], tri[:, (k + 2) % 3] - tri[:, k]
        cos = (a * b).sum(1) / np.linalg.norm(a, axis=1) / np.linalg.norm(b, axis=1)
        best = min(best, float(np.degrees(np.arccos(np.clip(cos, -1, 1))).min()))
    return best


def test_level_set_cut_of_a_tube_is_exact_on_the_level_set():
    """A linear field z − z0 on a prism tube: without snapping the part is {z ≤ z0} exactly (its border is
    on the plane, its area is the perimeter of the polygon times the height); orientation is kept."""
    rings = np.array([-0.5, -0.3, -0.12, 0.05, 0.2, 0.4])
    verts, faces = tube(rings, twist=np.pi / 24)
    z0 = 0.1
    cut = level_set_cut(verts, faces, z0 - verts[:, 2], snap=0.0)
    part = cut.apply(verts)
    loops, per_vertex = loop_stats(part, cut.faces)
    assert (per_vertex == 2).all()
    heights = sorted(float(loop[:, 2].mean()) for loop in loops)
    assert heights[0] == pytest.approx(-0.5) and heights[1] == pytest.approx(z0, abs=1e-12)
    top = min(loops, key=lambda lp: abs(lp[:, 2].mean() - z0))
    np.testing.assert_allclose(top[:, 2], z0, atol=1e-12)  # every border vertex on the level set
    side = 2 * 0.3 * np.sin(np.pi / 24)  # the regular 24-gon's side
    area = trimesh.Trimesh(part, cut.faces, process=False).area
    # twisted rings: the side walls are not planar, but z is linear on every triangle: area up to z0 is the
    # sum of the triangles' areas below the plane; compare with the untwisted prism's exact value instead
    flat_v, flat_f = tube(rings)
    flat = level_set_cut(flat_v, flat_f, z0 - flat_v[:, 2], snap=0.0)
    flat_area = trimesh.Trimesh(flat.apply(flat_v), flat.faces, process=False).area
    assert flat_area == pytest.approx(24 * side * (z0 + 0.5), rel=1e-12)
    assert area > flat_area  # the twisted walls are longer
    # orientation: each new triangle faces the way its parent does (outward, like the tube's)
    normals = trimesh.Trimesh(part, cut.faces, process=False).face_normals
    centres = part[cut.faces].mean(1)
    assert (np.einsum("ij,ij->i", normals[:, :2], centres[:, :2]) > 0).all()


def test_level_set_cut_snaps_instead_of_leaving_slivers():
    """A level just above a ring: the exact cut would leave triangles of 1/100 of an edge; with snapping the
    border goes through the ring's vertices (within ``snap`` of an edge of the level set), the part is a
    manifold with one border loop per end, and no triangle angle is below 10°."""
    rings = np.array([-0.5, -0.25, 0.0, 0.25, 0.5])
    verts, faces = tube(rings, twist=np.pi / 24)
    z0 = 0.0025  # 1% of the 0.25 ring spacing above the middle ring
    exact = level_set_cut(verts, faces, z0 - verts[:, 2], snap=0.0)
    assert smallest_angle(exact.apply(verts), exact.faces) < 2.0
    cut = level_set_cut(verts, faces, z0 - verts[:, 2], snap=0.2)
    part = cut.apply(verts)
    loops, per_vertex = loop_stats(part, cut.faces)
    assert len(loops) == 2 and (per_vertex == 2).all()
    top = max(loops, key=lambda lp: lp[:, 2].mean())
    assert np.abs(top[:, 2] - z0).max() <= 0.2 * 0.25
    assert smallest_angle(part, cut.faces) > 10.0


def test_part_cut_follows_every_body_of_the_topology():
    """The cut is affine combinations of the mesh's vertices: applied to an affinely moved body it gives the
    moved part (rows sum to one), so parts of different bodies correspond vertex by vertex."""
    verts, faces = tube(np.linspace(-0.5, 0.5, 7), twist=0.1)
    rng = np.random.default_rng(1)
    field = 0.13 - verts[:, 2] + 0.05 * np.sin(3 * np.arctan2(verts[:, 1], verts[:, 0]))  # a wavy level
    cut = level_set_cut(verts, faces, field)
    np.testing.assert_allclose(np.asarray(cut.weights.sum(1)).ravel(), 1.0, atol=1e-12)
    mat, shift = rng.standard_normal((3, 3)), rng.standard_normal(3)
    np.testing.assert_allclose(cut.apply(verts @ mat.T + shift), cut.apply(verts) @ mat.T + shift, atol=1e-12)
    # the border follows the wave: the interpolated field vanishes on the crossing points
    loops, per_vertex = loop_stats(cut.apply(verts), cut.faces)
    assert len(loops) == 2 and (per_vertex == 2).all()
    crossing = np.flatnonzero(np.diff(cut.weights.indptr) == 2)
    np.testing.assert_allclose(cut.weights[crossing] @ field, 0.0, atol=1e-12)


def test_smooth_label_field_cuts_a_labelled_band_along_a_smooth_curve():
    """FAUST-style per-face labels with a zigzag border become a border within one ring of the label's
    mean height, turning less at its vertices than the zigzag."""
    rings = np.linspace(-0.5, 0.5, 11)
    verts, faces = tube(rings, sides=32)
    centres = verts[faces].mean(1)
    ang = np.arctan2(centres[:, 1], centres[:, 0])
    in_part = centres[:, 2] < 0.05 * np.sign(np.sin(8 * ang))  # a zigzag label border
    field = smooth_label_field(faces, in_part, len(verts))
    cut = level_set_cut(verts, faces, field - 0.5)
    loops, per_vertex = loop_stats(cut.apply(verts), cut.faces)
    assert len(loops) == 2 and (per_vertex == 2).all()
    top = max(loops, key=lambda lp: lp[:, 2].mean())
    assert np.abs(top[:, 2]).max() <= 0.1 + 1e-9  # within one ring (0.1) of z = 0
    sawtooth = PartCut.from_faces(len(verts), faces, select_faces(faces, in_part))
    saw_loops = mesh_boundary_loops(verts, sawtooth.faces)
    saw_top = max(saw_loops, key=lambda lp: lp[:, 2].mean())
    assert turning(top).mean() < 0.6 * turning(saw_top).mean()


def turning(loop: np.ndarray) -> np.ndarray:
    a, b = loop - np.roll(loop, 1, 0), np.roll(loop, -1, 0) - loop
    cos = (a * b).sum(1) / np.linalg.norm(a, axis=1) / np.linalg.norm(b, axis=1)
    return np.degrees(np.arccos(np.clip(cos, -1, 1)))


def test_anny_smooth_borders_are_smoother_than_mesh_edge_cuts():
    """The generator's default cut: hands keep one wrist loop, whose vertices turn far less than the
    dominant-bone cut's sawtooth; the triangles it adds are no thinner than the body mesh's own."""
    model = anny_model()
    smooth, faces_cut = (anny_parts(1, seed=3, model=model, categories=["hands"], border=b)["hands"]
                         for b in ("smooth", "faces"))
    (v_s,), f_s, _ = smooth
    (v_f,), f_f, _ = faces_cut
    (loop_s,), (loop_f,) = mesh_boundary_loops(v_s, f_s), mesh_boundary_loops(v_f, f_f)
    assert turning(loop_s).mean() < 0.5 * turning(loop_f).mean()
    assert smallest_angle(v_s, f_s) >= smallest_angle(v_f, f_f) - 1e-6
    with pytest.raises(DatasetError, match="border='zigzag'"):
        anny_parts(1, model=model, border="zigzag")


def test_make_dataset_border_flag(tmp_path, capsys):
    """--border is written to meta.json; on the fixture (each label a whole piece) both cuts give the same
    meshes; an unknown border stops argparse with status 2."""
    import json

    write_faust_fixture(tmp_path)
    for border in ("faces", "smooth"):
        main(["--source", "faust", "--faust-root", str(tmp_path), "--out", str(tmp_path / border),
              "--border", border, "--categories", "hands"])
        meta = json.loads((tmp_path / border / "faust" / "hands" / "meta.json").read_text())
        assert meta["border"] == border and meta["count"] == 3
    a = trimesh.load(tmp_path / "faces" / "faust" / "hands" / "001.ply", process=False)
    b = trimesh.load(tmp_path / "smooth" / "faust" / "hands" / "001.ply", process=False)
    np.testing.assert_array_equal(a.faces, b.faces)
    np.testing.assert_allclose(a.vertices, b.vertices, atol=1e-7)
    with pytest.raises(SystemExit) as err:
        main(["--source", "faust", "--faust-root", str(tmp_path), "--border", "zigzag"])
    assert err.value.code == 2 and "zigzag" in capsys.readouterr().err


def test_make_dataset_refuses_no_bodies_and_an_unwritable_folder_before_generating(tmp_path, capsys):
    """--num 0 (an IndexError deep in the generator before) and an --out that cannot be created (a
    FileNotFoundError after minutes of generating) are one sentence each, before any body is made."""
    with pytest.raises(SystemExit) as err:
        main(["--num", "0"])
    assert err.value.code == 2 and "--num=0 must be at least 1" in capsys.readouterr().err
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    with pytest.raises(SystemExit) as err:
        main(["--num", "1", "--out", str(blocker / "data")])
    assert err.value.code == 2
    assert capsys.readouterr().err.startswith(f"error: --out='{blocker / 'data'}' cannot be created")


@pytest.mark.parametrize("fault", ["words in the labels", "an unreadable mesh", "no segmentation", "no root"])
def test_make_dataset_refuses_bad_faust_files_in_one_sentence_and_leaves_no_folder(tmp_path, capsys, fault):
    """FAUST files from elsewhere: words in the label file (numpy's ValueError before), a mesh that is not one
    (trimesh's), a missing label file or root end with one sentence naming the file and status 2, as argparse's
    own errors do, and the refused run leaves no empty --out folder behind."""
    write_faust_fixture(tmp_path)
    seg = tmp_path / "segs" / "train" / "faust" / "faust_corrected.txt"
    root, named = tmp_path, seg
    if fault == "words in the labels":
        seg.write_text("hello world\n" + seg.read_text())
    elif fault == "an unreadable mesh":
        named = tmp_path / "meshes" / "train" / "faust" / "tr_reg_001.ply"
        named.write_text("garbage")
    elif fault == "no segmentation":
        seg.unlink()
    else:
        root = named = tmp_path / "missing"
    out = tmp_path / "out" / "data"
    with pytest.raises(SystemExit) as err:
        main(["--source", "faust", "--faust-root", str(root), "--out", str(out), "--categories", "hands"])
    message = capsys.readouterr().err
    assert err.value.code == 2 and message.startswith("error: ") and str(named) in message
    assert "Traceback" not in message and len(message.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()


def test_snapping_never_pinches_a_saddle():
    """A saddle field x·y + ε on a flat grid: the crossings next to the centre are within ``snap`` of it, but
    snapping the centre onto the level set would pinch the part there (two border arcs through one vertex)
    and, reduced to one component, keep only one of its two quadrants; the cut keeps the centre's own value
    instead: one manifold part with both quadrants."""
    h = 0.25
    xs = np.arange(-4, 5) * h
    gx, gy = np.meshgrid(xs, xs, indexing="ij")
    verts = np.c_[gx.ravel(), gy.ravel(), np.zeros(gx.size)]
    n = len(xs)
    faces = []
    for i in range(n - 1):
        for j in range(n - 1):
            a, b, c, d = i * n + j, (i + 1) * n + j, (i + 1) * n + j + 1, i * n + j + 1
            faces += [[a, b, d], [b, c, d]]  # diagonals along (1, −1): the centre sees both negative wedges
    faces = np.array(faces)
    field = verts[:, 0] * verts[:, 1] + 1e-3
    centre = n * n // 2
    edges = np.unique(np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1), axis=0)
    ring = np.unique(edges[(edges == centre).any(1)])
    assert (field[ring] < 0).sum() == 2  # a saddle: two negative neighbours, apart
    cut = level_set_cut(verts, faces, field, snap=0.2)
    _, per_vertex = loop_stats(cut.apply(verts), cut.faces)
    assert (per_vertex == 2).all()
    part = cut.apply(verts)
    assert trimesh.Trimesh(part, cut.faces, process=False).area > 1.95  # both unit quadrants {x·y > 0}
    assert np.abs(part).sum(1).min() == 0.0  # the centre is still a vertex of the part


def test_make_dataset_removes_the_numbered_parts_of_an_earlier_larger_generation(tmp_path, caplog):
    """Training picks data.index by rank among the folder's .ply files: a second, smaller generation into the same
    --out left 002.ply of the first behind, to pass for a part of the new one. The categories it rewrites keep only
    the new parts (and a log line says what went), every other file stays, and a category not rewritten is left."""
    import logging

    write_faust_fixture(tmp_path / "faust")
    out = tmp_path / "out"
    main(["--source", "faust", "--faust-root", str(tmp_path / "faust"), "--out", str(out),
          "--categories", "hands", "feet"])
    hands = out / "faust" / "hands"
    for name in ("scan.ply", "notes.txt"):
        (hands / name).write_text("the user's own")
    (tmp_path / "faust" / "meshes" / "train" / "faust" / "tr_reg_002.ply").unlink()  # two bodies now
    with caplog.at_level(logging.INFO, logger="deepcurrents.make_dataset"):
        main(["--source", "faust", "--faust-root", str(tmp_path / "faust"), "--out", str(out),
              "--categories", "hands"])
    assert sorted(p.name for p in hands.iterdir()) == ["000.ply", "001.ply", "meta.json", "notes.txt", "scan.ply"]
    assert [r.getMessage() for r in caplog.records if "earlier, larger generation" in r.getMessage()] == \
        [f"{hands}: removed 1 part file(s) of an earlier, larger generation (002.ply)"]
    assert sorted(p.name for p in (out / "faust" / "feet").glob("*.ply")) == ["000.ply", "001.ply", "002.ply"]
    # only names write_parts gives (three digits at least, no padding beyond) are numbered parts
    from deepcurrents.cli.make_dataset import remove_stale_parts

    for name in ("0005.ply", "7.ply", "1000.ply", "004.ply"):
        (hands / name).write_text("")
    assert [p.name for p in remove_stale_parts(hands, 2)] == ["004.ply", "1000.ply"]
    assert (hands / "0005.ply").exists() and (hands / "7.ply").exists() and (hands / "001.ply").exists()


def test_make_dataset_refuses_an_empty_category_list(tmp_path, capsys):
    """`--categories` with no names wrote nothing and exited 0; it is one sentence naming the categories and
    status 2, as argparse's own refusals, before any folder is made."""
    write_faust_fixture(tmp_path)
    with pytest.raises(SystemExit) as err:
        main(["--source", "faust", "--faust-root", str(tmp_path), "--out", str(tmp_path / "out"), "--categories"])
    message = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.value.code == 2
    assert message.endswith(f"error: --categories needs at least one of {', '.join(CATEGORIES)} (or give "
                            "--whole-bodies N or --joined-parts N).")
    assert not (tmp_path / "out").exists()


def test_an_unknown_category_names_the_categories(tmp_path):
    """data.category=hand (misspelt) said to run `make data`, which never builds 'hand': it names the categories.
    A known category that is not built yet still says how to build it, and a folder of the user's own is used."""
    with pytest.raises(DatasetError, match=r"^data\.category='hand' is not a dataset category; choose one of "
                                           r"heads, hands, forearms, arms, torsos, feet\.$"):
        dataset_path(tmp_path, "anny", "hand", 0)
    with pytest.raises(DatasetError, match="make data"):
        dataset_path(tmp_path, "anny", "hands", 0)
    (tmp_path / "anny" / "hand").mkdir(parents=True)
    (tmp_path / "anny" / "hand" / "000.ply").write_text("")
    assert dataset_path(tmp_path, "anny", "hand", 0) == tmp_path / "anny" / "hand" / "000.ply"
