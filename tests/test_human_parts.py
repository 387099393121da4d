"""Human-part datasets: the Anny generator on two bodies and the FAUST loader on a fixture in the
segmentation benchmark's layout that the test writes itself."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from deepcurrents.cli.make_dataset import main
from deepcurrents.data.human_parts import (
    CATEGORIES,
    DatasetError,
    anny_model,
    anny_parts,
    dataset_path,
    faust_parts,
    kabsch_rotation,
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


def test_dataset_errors_say_what_to_do(tmp_path):
    with pytest.raises(DatasetError, match="make data"):
        dataset_path(tmp_path, "anny", "hands", 0)
    with pytest.raises(DatasetError, match="is not a directory"):
        faust_parts(tmp_path)
    with pytest.raises(SystemExit, match="--faust-root is required"):
        main(["--source", "faust", "--out", str(tmp_path)])
