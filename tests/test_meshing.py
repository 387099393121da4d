"""Meshing pieces against exact geometry: clipping on an iso-line, border loops, closing a border onto Γ."""

import math

import numpy as np
import pytest
import torch
import trimesh

from deepcurrents.eval.meshing import METHODS, MeshMethod, clip_by_field, extract_surface, zip_to_loop
from deepcurrents.eval.metrics import boundary_error
from deepcurrents.geometry import circle
from deepcurrents.geometry.topology import border_loops


def grid_square(n=40, half=1.0):
    """A triangulated square [-half, half]^2 in the plane z = 0, normals +z."""
    g = np.linspace(-half, half, n + 1)
    xx, yy = np.meshgrid(g, g, indexing="ij")
    verts = np.stack([xx.ravel(), yy.ravel(), np.zeros(xx.size)], 1)
    idx = np.arange(verts.shape[0]).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return verts, faces


def test_clip_by_linear_field_is_exact():
    verts, faces = grid_square(17)
    # keep x + 0.3 y ≥ 0.1: a half-plane cut through the square; linear fields are clipped exactly
    v, f = clip_by_field(verts, faces, verts[:, 0] + 0.3 * verts[:, 1] - 0.1)
    area = trimesh.Trimesh(v, f, process=False).area
    # exact area of {x + 0.3y ≥ 0.1} ∩ [-1,1]^2 = ∫_{-1}^{1} (1 − (0.1 − 0.3 y)) dy
    assert math.isclose(area, 2 * 0.9, rel_tol=1e-9)
    m = trimesh.Trimesh(v, f)
    assert m.is_winding_consistent and len(m.split(only_watertight=False)) == 1


def test_clip_keeps_the_disk_and_border_loops_follow_the_faces():
    verts, faces = grid_square(80)
    v, f = clip_by_field(verts, faces, 0.5 - np.linalg.norm(verts[:, :2], axis=1))
    area = trimesh.Trimesh(v, f, process=False).area
    assert abs(area - math.pi * 0.25) < 2e-3
    (loop,) = border_loops(f)
    pts = v[loop]
    assert np.allclose(np.linalg.norm(pts[:, :2], axis=1), 0.5, atol=2e-3)
    # faces have +z normals, so the border runs counter-clockwise seen from +z: positive signed area
    signed = 0.5 * np.sum(pts[:, 0] * np.roll(pts[:, 1], -1) - np.roll(pts[:, 0], -1) * pts[:, 1])
    assert signed > 0


def test_zip_closes_an_annulus_onto_the_curve():
    verts, faces = grid_square(80)
    v, f = clip_by_field(verts, faces, 0.45 - np.linalg.norm(verts[:, :2], axis=1))
    (border,) = border_loops(f)
    gamma = circle(0.6, n=300)
    for loop in (gamma, gamma[::-1]):  # either orientation of Γ
        new_v, new_f = zip_to_loop(v, border, loop)
        mesh = trimesh.Trimesh(np.concatenate([v, new_v]), np.concatenate([f, new_f]))
        assert abs(mesh.area - math.pi * 0.36) < 3e-3
        assert mesh.is_winding_consistent
        assert (mesh.face_normals[:, 2] > 0).all()
        assert boundary_error(mesh, [loop]) < 1e-9


def test_zip_refuses_a_border_that_does_not_wind_once():
    verts, faces = grid_square(40)
    v, f = clip_by_field(verts, faces, 0.2 - np.linalg.norm(verts[:, :2] - [0.5, 0.0], axis=1))
    (border,) = border_loops(f)  # a small disk off-centre: it does not go around the curve
    assert zip_to_loop(v, border, circle(0.3, n=100)) is None


def test_border_loops_split_where_two_loops_touch_at_a_vertex():
    """A bowtie (two triangles sharing only vertex 0): two border edges leave vertex 0, and both loops are
    found, each edge once; the border segments of the metrics are every border edge."""
    from deepcurrents.eval.metrics import mesh_border_segments

    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [-1, 0, 0], [-1, -1, 0]], dtype=float)
    f = np.array([[0, 1, 2], [0, 3, 4]])
    loops = border_loops(f)
    assert sorted(sorted(lp.tolist()) for lp in loops) == [[0, 1, 2], [0, 3, 4]]
    for lp in loops:  # each follows its face's orientation
        face = f[0] if 1 in lp else f[1]
        assert any(np.array_equal(np.roll(lp, k), face) for k in range(3))
    starts, ends = mesh_border_segments(trimesh.Trimesh(v, f, process=False))
    assert len(starts) == 6
    assert boundary_error(trimesh.Trimesh(v, f, process=False), [v[[0, 1, 2]], v[[0, 3, 4]]]) < 1e-9


class PlaneMethod(MeshMethod):
    """A meshing method written for this test: the plane x·n = 0 (exact field, exact Newton residual)."""

    name = "plane"
    normal = torch.tensor([1.0, 1.0, 1.0]) / math.sqrt(3.0)

    def sample(self, points, shape, loops, voxel):
        return (points.double() @ self.normal.double()).cpu().numpy().reshape(shape), 0.0

    @property
    def reported_level(self):
        return 0.0

    def empty_reason(self):
        return "The plane misses the meshing region"

    def residual(self, x):
        return x @ self.normal, self.normal.expand_as(x)


def test_a_new_meshing_method_is_one_class(monkeypatch):
    """extract_surface runs any MeshMethod registered in METHODS: the plane through a disk current (ω along
    n on the disk only) gives the region bounded by Γ, cut by |ω| and the tube and zipped onto Γ."""
    from test_render import AnalyticDisk

    monkeypatch.setitem(METHODS, "plane", PlaneMethod)
    n = PlaneMethod.normal.double().numpy()
    disk = AnalyticDisk(radius=0.5, normal=tuple(n))
    gamma = disk.loops[0].double().numpy()
    result = extract_surface(disk, resolution=40, method="plane")
    mesh = result.mesh
    assert result.zipped_loops == 1 and result.level == 0.0
    # exactly the polygon Γ spans: half the norm of Σ p_i × p_{i+1}
    polygon_area = 0.5 * np.linalg.norm(np.cross(gamma, np.roll(gamma, -1, 0)).sum(0))
    assert abs(mesh.area - polygon_area) < 1e-6 * polygon_area  # the paper-style cut: +2%
    assert np.abs(mesh.vertices @ n).max() < 1e-6 and boundary_error(mesh, [gamma]) < 1e-6
    assert (mesh.face_normals @ n > 0.999).all()  # oriented along the current
    with pytest.raises(ValueError, match="method='nope'"):
        extract_surface(disk, method="nope")
