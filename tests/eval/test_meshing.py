"""Meshing pieces against exact geometry: clipping on an iso-line, border loops, closing a border onto Γ."""

import math

import numpy as np
import pytest
import torch
import trimesh

from deepcurrents.data.targets import mesh_boundary_loops
from deepcurrents.eval.meshing import METHODS, MeshMethod, clip_by_field, extract_surface, zip_to_loop
from deepcurrents.eval.meshing.border import MAX_FLOATING, close_onto_loops, cut_tube
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


def test_a_tube_that_holds_the_whole_surface_is_named_as_the_cause(monkeypatch, caplog):
    """extract boundary_tube=5 cut every face away and the warning blamed the current (|ω| below δ)."""
    import logging

    from test_render import AnalyticDisk

    monkeypatch.setitem(METHODS, "plane", PlaneMethod)
    disk = AnalyticDisk(radius=0.5, normal=tuple(PlaneMethod.normal.double().numpy()))
    with caplog.at_level(logging.WARNING):
        result = extract_surface(disk, resolution=24, method="plane", boundary_tube=5.0)
    assert len(result.mesh.faces) == 0
    assert "boundary tube (radius 5 about Γ) holds the whole level set" in caplog.text
    assert "No part of the surface carries the current" not in caplog.text



def test_a_tube_widened_by_coarse_cells_is_said_and_names_the_resolution(monkeypatch, caplog):
    """At a low resolution the tube is 1.5 cells wide, not boundary_tube: the probe's trefoil meshed at 16 came out
    at 2.2× its area without a word, and at 8 the empty mesh said "lower boundary_tube", which could not help."""
    import logging
    import re

    from test_render import AnalyticDisk

    monkeypatch.setitem(METHODS, "plane", PlaneMethod)
    disk = AnalyticDisk(radius=0.5, normal=tuple(PlaneMethod.normal.double().numpy()))
    with caplog.at_level(logging.WARNING):
        extract_surface(disk, resolution=40, method="plane")  # 0.03-wide cells: 1.5 of them inside the 0.04 tube
    assert "widened" not in caplog.text
    with caplog.at_level(logging.WARNING):
        said = set()  # the warnings given in one chain of meshings (a family's members)
        extract_surface(disk, resolution=16, method="plane", said=said)
        extract_surface(disk, resolution=16, method="plane", said=said)  # the same grid again: not said again
    said = re.findall(r"resolution=16 gives ([\d.]+)-wide cells.*; resolution=(\d+) or more keeps it as set",
                      caplog.text)
    assert len(said) == 1
    cells, enough = float(said[0][0]), int(said[0][1])
    assert 1.5 * cells * 16 / enough <= 0.04 < 1.5 * cells * 16 / (enough - 1)  # the least resolution that keeps it
    caplog.clear()
    with caplog.at_level(logging.WARNING):  # cells a third of the disk wide: the tube holds all of it
        result = extract_surface(disk, resolution=3, method="plane")
    assert len(result.mesh.faces) == 0 and "raise resolution (the tube is 1.5 cells wide)" in caplog.text


class PinholedPlane(PlaneMethod):
    """The plane, with the one face whose centroid is nearest the disk's centre failing the carrying test (as
    a lone face under δ does inside a trained surface)."""

    name = "pinholed_plane"

    def keep_carrying(self, centroids, omega, min_alignment):
        keep = torch.ones(len(centroids), dtype=torch.bool)
        keep[centroids.norm(dim=-1).argmin()] = False
        return keep


def test_a_face_dropped_inside_the_surface_leaves_no_pinhole(monkeypatch):
    """A lone dropped face would leave a hole of three edges, which boundary_error reads as a tear (its
    distance from Γ): the mesh is the whole polygon Γ spans, its only border Γ."""
    from test_render import AnalyticDisk

    monkeypatch.setitem(METHODS, "pinholed_plane", PinholedPlane)
    n = PlaneMethod.normal.double().numpy()
    disk = AnalyticDisk(radius=0.5, normal=tuple(n))
    gamma = disk.loops[0].double().numpy()
    mesh = extract_surface(disk, resolution=40, method="pinholed_plane").mesh
    polygon_area = 0.5 * np.linalg.norm(np.cross(gamma, np.roll(gamma, -1, 0)).sum(0))
    assert abs(mesh.area - polygon_area) < 1e-6 * polygon_area
    assert boundary_error(mesh, [gamma]) < 1e-6 and len(mesh_boundary_loops(mesh.vertices, mesh.faces)) == 1
    assert mesh.is_winding_consistent and (mesh.face_normals @ n > 0.999).all()

# --- a cap across the opening: two cut border loops along one loop of Γ (reconstructions' wrists and necks) ---

def revolve(profile, n=128):
    """Surface of revolution about z of a profile (K, 2) of (ρ, z); a profile point on the axis (ρ = 0) is one
    vertex. Faces are oriented with normals ρ̂·(dz/ds) − ẑ·(dρ/ds) (outward for a profile climbing at ρ > 0).
    → vertices (V, 3), faces (F, 3)."""
    t = 2 * np.pi * np.arange(n) / n
    index, verts = [], []
    for rho, z in profile:
        if rho == 0:
            index.append(np.full(n, len(verts)))
            verts.append([0.0, 0.0, z])
        else:
            index.append(len(verts) + np.arange(n))
            verts += np.stack([rho * np.cos(t), rho * np.sin(t), np.full(n, z)], 1).tolist()
    faces = []
    for lo, hi in zip(index[:-1], index[1:], strict=True):
        lo1, hi1 = np.roll(lo, -1), np.roll(hi, -1)
        faces += [np.stack([lo, lo1, hi1], 1), np.stack([lo, hi1, hi], 1)]
    faces = np.concatenate(faces)
    faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 2] != faces[:, 0])]
    return np.asarray(verts), faces


def cup_profile(radius, height, k=24):
    """A cup open at z = 0: the wall ρ = R up to z = h, then a hemisphere to the pole. (K, 2)."""
    wall = np.stack([np.full(k, radius), np.linspace(0, height, k)], 1)
    phi = np.linspace(0, np.pi / 2, k)[1:]
    dome = np.stack([radius * np.cos(phi), height + radius * np.sin(phi)], 1)
    dome[-1, 0] = 0.0
    return np.concatenate([wall, dome])


def merge(*meshes):
    """One (vertices, faces) of several."""
    verts, faces, base = [], [], 0
    for v, f in meshes:
        verts.append(v)
        faces.append(f + base)
        base += len(v)
    return np.concatenate(verts), np.concatenate(faces)


def polygonal_area(verts, faces):
    return trimesh.Trimesh(verts, faces, process=False).area


@pytest.mark.parametrize("flip", [False, True])
def test_a_cap_beyond_the_opening_is_dropped_and_the_part_closed_onto_gamma(flip):
    """The target is a cup (outward normals); Γ is its rim with Stokes' orientation (data.targets), and the
    current's surface is the cup with faces against those normals. A level set that also holds a cap just
    beyond the opening (a disk at z = −d that seals the cup, oriented as the sealed cup's) has two cut border
    loops along Γ, running opposite ways. The closer zips the cup's, drops the cap: the mesh is the cup
    plus the strip onto Γ, area that of the cup itself (independent of τ), border Γ. ``flip``: the opposite
    current (every face and Γ reversed) gives the same surface."""
    radius, height, d, tube = 0.3, 0.3, 0.02, 0.04
    cup_v, cup_f = revolve(cup_profile(radius, height))
    (gamma,) = mesh_boundary_loops(cup_v, cup_f)
    assert np.allclose(gamma[:, 2], 0) and np.allclose(np.linalg.norm(gamma[:, :2], axis=1), radius)
    cup_area = polygonal_area(cup_v, cup_f)
    # cap: a disk at z = −d; its profile climbs outwards, so revolve's normals point −z: flip to +z (into the cup)
    cap_v, cap_f = revolve(np.stack([np.linspace(0, radius, 16), np.full(16, -d)], 1))
    cap_f = cap_f[:, ::-1]
    verts, faces = merge((cup_v, cup_f[:, ::-1]), (cap_v, cap_f))  # the sealed cup, normals inward (along ω)
    if flip:
        faces, gamma = faces[:, ::-1], gamma[::-1]
    assert trimesh.Trimesh(*merge((cup_v, cup_f[:, ::-1]), (cap_v, cap_f)), process=True).is_winding_consistent

    v, f = cut_tube(verts, faces, [gamma], tube)
    assert len(border_loops(f)) == 2  # the cup's cut border and the cap's, both along Γ
    new_v, new_f, zipped = close_onto_loops(v, f, [gamma], 0.01, tube)
    mesh = trimesh.Trimesh(new_v, new_f, process=True)
    mesh.remove_unreferenced_vertices()
    assert zipped == 1
    assert boundary_error(mesh, [gamma]) < 1e-9
    assert mesh.vertices[:, 2].min() > -1e-9  # nothing of the cap is left
    assert len(mesh.split(only_watertight=False)) == 1 and mesh.is_winding_consistent
    # the strip spans the cut wall between z = 0 and z = τ: the same polygonal cylinder, so the area is the cup's
    assert mesh.area == pytest.approx(cup_area, rel=2e-3)
    assert cup_area == pytest.approx(2 * np.pi * radius * height + 2 * np.pi * radius**2, rel=2e-3)


def test_of_two_sheets_leaving_gamma_the_same_way_the_larger_is_kept():
    """Two parallel disks spanning Γ (z = 0 and z = d < τ), faces the same way: both cut borders run along Γ
    the current's way. One closed surface comes out, the larger cut piece (the offset disk, cut at
    ρ = R − √(τ² − d²) instead of R − τ) zipped onto Γ: a disk of radius r and the cone strip from it to Γ."""
    radius, d, tube = 0.3, 0.02, 0.04
    gamma = circle(radius, n=128)[::-1]  # disks with +z normals run counter-clockwise: Γ the other way
    disk = np.stack([np.linspace(0, radius, 16), np.zeros(16)], 1)
    low_v, low_f = revolve(disk)
    high_v, high_f = revolve(disk + [0, d])
    verts, faces = merge((low_v, low_f[:, ::-1]), (high_v, high_f[:, ::-1]))  # both +z
    v, f = cut_tube(verts, faces, [gamma], tube)
    new_v, new_f, zipped = close_onto_loops(v, f, [gamma], 0.01, tube)
    mesh = trimesh.Trimesh(new_v, new_f, process=True)
    mesh.remove_unreferenced_vertices()
    assert zipped == 1 and boundary_error(mesh, [gamma]) < 1e-9
    assert len(mesh.split(only_watertight=False)) == 1 and mesh.is_winding_consistent
    r = radius - math.sqrt(tube**2 - d**2)
    assert mesh.area == pytest.approx(math.pi * r**2 + math.pi * (radius + r) * tube, rel=3e-3)
    assert mesh.vertices[:, 2].max() == pytest.approx(d) and (mesh.face_normals[:, 2] > 0).all()


def test_one_border_along_gamma_is_zipped_whichever_way_it_runs():
    """A single cut border along a loop is zipped as before, whatever its direction (a current given by
    hand need not follow α's convention)."""
    verts, faces = grid_square(80)
    v, f = clip_by_field(verts, faces, 0.45 - np.linalg.norm(verts[:, :2], axis=1))
    for gamma in (circle(0.5, n=200), circle(0.5, n=200)[::-1]):
        _, _, zipped = close_onto_loops(v, f, [gamma], 0.01, 0.05)
        assert zipped == 1


@pytest.mark.parametrize("cap_radius, dropped", [(0.07, True), (0.12, False)])
def test_a_loose_cap_joined_to_no_loop_is_dropped_once_the_surface_is_zipped(cap_radius, dropped):
    """A disk spanning Γ (R = 0.3) and a small disk beside it that no border of Γ's tube reaches (a loose cap,
    z = −0.1, its border not along Γ): the disk is zipped onto Γ and the loose piece dropped while it is below
    MAX_FLOATING of the area before zipping (π·0.07² is 6.8 % of it with the disk cut at R − τ; π·0.12² is
    17.6 %, kept for boundary_error to show).
    Without a zipped piece (Γ far from both) nothing is dropped."""
    assert MAX_FLOATING == 0.1
    radius, tube = 0.3, 0.04
    gamma = circle(radius, n=128)[::-1]
    disk_v, disk_f = revolve(np.stack([np.linspace(0, radius, 16), np.zeros(16)], 1))
    cap_v, cap_f = revolve(np.stack([np.linspace(0, cap_radius, 8), np.full(8, -0.1)], 1))
    verts, faces = merge((disk_v, disk_f[:, ::-1]), (cap_v, cap_f[:, ::-1]))
    v, f = cut_tube(verts, faces, [gamma], tube)
    assert len(border_loops(f)) == 2
    new_v, new_f, zipped = close_onto_loops(v, f, [gamma], 0.01, tube)
    mesh = trimesh.Trimesh(new_v, new_f, process=True)
    mesh.remove_unreferenced_vertices()
    assert zipped == 1
    assert (mesh.vertices[:, 2].min() > -1e-9) == dropped
    assert len(mesh.split(only_watertight=False)) == (1 if dropped else 2)
    if dropped:
        assert boundary_error(mesh, [gamma]) < 1e-9
    far = circle(radius, center=(0.0, 0.0, 0.5), n=128)  # no border runs along it: left open, nothing dropped
    _, kept_f, none = close_onto_loops(v, f, [far], 0.01, tube)
    assert none == 0 and len(kept_f) == len(f)


def test_a_strip_in_rows_is_the_same_surface_without_slivers():
    """The annulus zipped onto a circle of radius 0.6 (strip 0.15 wide) in one row is made of triangles
    0.15 long on edges of about 0.01: slivers. In 12 rows it is the same flat region (area π·0.36 as for
    one row, border Γ, normals +z) in triangles whose smallest angle is typically over 30° (median; 4.8° in
    one row), none thinner than the clipped disk's own thinnest (0.8°)."""
    verts, faces = grid_square(80)
    v, f = clip_by_field(verts, faces, 0.45 - np.linalg.norm(verts[:, :2], axis=1))
    (border,) = border_loops(f)
    gamma = circle(0.6, n=300)
    inner = np.degrees(trimesh.Trimesh(v, f, process=False).face_angles.min(1)).min()
    for rows, (lo, hi) in ((1, (0, 5)), (12, (30, 90))):
        new_v, new_f = zip_to_loop(v, border, gamma, rows)
        strip = trimesh.Trimesh(np.concatenate([v, new_v]), new_f, process=False)
        mesh = trimesh.Trimesh(np.concatenate([v, new_v]), np.concatenate([f, new_f]))
        assert abs(mesh.area - math.pi * 0.36) < 3e-3 and boundary_error(mesh, [gamma]) < 1e-9
        assert mesh.is_winding_consistent and (mesh.face_normals[:, 2] > 0).all()
        smallest = np.degrees(strip.face_angles.min(1))
        assert lo < np.median(smallest) < hi
        assert rows == 1 or smallest.min() > inner


class SealedCup(torch.nn.Module):
    """A current whose f is a smoothed indicator of a cup sealed just beyond its opening: the cup of
    ``cup_profile`` (open at z = 0, rim Γ) closed by a flat bottom at z = −d. Its level set f = s (s = mean of
    f over Γ, which lies on the sealed surface) is the cup and the cap both, as a reconstruction's wrist is;
    ω = ∇f + alpha_scale·α_Γ with Γ the cup's Stokes rim for outward normals (counter-clockwise from +z)."""

    def __init__(self, radius=0.3, height=0.3, d=0.02, width=0.02, alpha_scale=1e-3):
        super().__init__()
        self.dim, self.alpha_scale = 3, alpha_scale
        self.radius, self.height, self.d, self.width = radius, height, d, width
        self.loops = [torch.as_tensor(circle(radius, n=96), dtype=torch.float32)]

    def f(self, x):
        rho, z = x[:, :2].norm(dim=-1), x[:, 2]
        wall = torch.maximum(rho - self.radius, -self.d - z)
        dome = (x - x.new_tensor([0.0, 0.0, self.height])).norm(dim=-1) - self.radius
        return torch.sigmoid(-torch.where(z > self.height, dome, wall) / self.width)

    def alpha(self, x):
        from deepcurrents.geometry import biot_savart

        return self.alpha_scale * biot_savart(x, self.loops)

    def evaluate(self, x, chunk_size=1 << 15, omega=True):
        with torch.enable_grad():
            xg = x.detach().requires_grad_(True)
            f = self.f(xg)
            (grad,) = torch.autograd.grad(f.sum(), xg)
        return (f.detach(), grad + self.alpha(x)) if omega else f.detach()


def test_level_set_of_a_sealed_cup_gives_the_cup_closed_onto_gamma():
    """extract_surface (level set) on a field whose f = s holds the cup and a cap across its opening: the
    mesh is the cup alone, its border Γ, its area the cup's 2πRh + 2πR², in strip rows about a voxel tall."""
    cup = SealedCup()
    rim_v, rim_f = revolve(cup_profile(cup.radius, cup.height), 96)
    (stokes_rim,) = mesh_boundary_loops(rim_v, rim_f)
    assert np.allclose(stokes_rim, cup.loops[0].double().numpy(), atol=1e-6)  # the outward cup's Stokes rim is Γ
    bounds = np.array([[-0.4, -0.4, -0.12], [0.4, 0.4, 0.7]])
    result = extract_surface(cup, resolution=40, bounds=bounds, method="level_set")
    mesh, gamma = result.mesh, cup.loops[0].double().numpy()
    assert result.zipped_loops == 1 and boundary_error(mesh, [gamma]) < 1e-6
    assert mesh.vertices[:, 2].min() > -1e-6  # the cap is gone
    assert len(mesh.split(only_watertight=False)) == 1 and mesh.is_winding_consistent
    assert mesh.area == pytest.approx(2 * np.pi * cup.radius * cup.height + 2 * np.pi * cup.radius**2, rel=0.02)


def test_closed_bubbles_are_dropped_and_sheets_with_a_border_kept():
    """A closed sphere (no border edge: a cycle, it spans nothing) is dropped with its exact mesh area; an open
    disk and a sphere with one face missing (it has a border) are kept."""
    from deepcurrents.eval.meshing.surface import _drop_closed_components

    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.2)
    ring = circle(0.3, n=32)  # a fan over a circle: an open disk
    disk = trimesh.Trimesh(np.vstack([[0.0, 0.0, 0.0], ring]) + [1.0, 0, 0],
                           [[0, 1 + i, 1 + (i + 1) % 32] for i in range(32)], process=False)
    open_sphere = trimesh.Trimesh(sphere.vertices + [0, 1.0, 0], sphere.faces[1:])
    parts = [sphere, disk, open_sphere]
    verts = np.concatenate([p.vertices for p in parts])
    offsets = np.cumsum([0] + [len(p.vertices) for p in parts[:-1]])
    faces = np.concatenate([p.faces + o for p, o in zip(parts, offsets, strict=True)])
    kept, dropped = _drop_closed_components(verts, faces)
    assert dropped == pytest.approx(sphere.area, rel=1e-12)
    assert len(kept) == len(disk.faces) + len(open_sphere.faces)
    assert set(np.unique(kept)) == set(range(len(sphere.vertices), len(verts)))


def test_phase_curve_of_an_untrained_2d_current_is_the_segment():
    """f ≡ const (zero-initialised output): φ = const/s + angle(x − p₊) − angle(x − p₋), whose level sets are
    the circular arcs through the two points; off the curve (most of the box) φ ≈ its far value, so the level
    opposite it is the straight segment (the 2D analogue of the flat disk of a planar circle). The paper's level
    set f = s finds nothing in a constant f."""
    from deepcurrents.eval.meshing import extract_curve_2d
    from deepcurrents.eval.metrics import curve_boundary_error, curve_length
    from deepcurrents.nn import neural_current

    torch.manual_seed(0)
    current = neural_current(dim=2, poles=torch.tensor([[-0.5, 0.0], [0.5, 0.0]]), signs=torch.tensor([-1.0, 1.0]),
                            num_frequencies=8, width=8, depth=1).eval()
    # 127 cells: no grid row on y = 0, where sin(φ − θ) would vanish exactly at the nodes of this symmetric case
    # δ = 0: the untrained |ω| = s|α| is below the default δ in the middle of the segment
    curves = extract_curve_2d(current, resolution=127, delta=0.0, method="phase")
    assert len(curves) == 1 and abs(curve_length(curves) - 1.0) < 0.01
    assert np.abs(curves[0][:, 1]).max() < 2.0 / 127  # on y = 0, within a grid cell
    poles = current.poles.double().numpy()
    assert curve_boundary_error(curves, poles) < 1e-12  # the segment ends on both points
    # the default δ drops the middle, where the untrained |ω| is small: two pieces, each from a point to a loose end
    broken = extract_curve_2d(current, resolution=127, method="phase")
    assert len(broken) == 2 and curve_length(broken) < 0.9
    ends = np.concatenate([[c[0], c[-1]] for c in broken])
    loose = np.linalg.norm(ends[:, None] - poles[None], axis=-1).min(1).max()
    assert loose > 0.05 and curve_boundary_error(broken, poles) == pytest.approx(loose)
    assert curve_boundary_error([], poles) is None
    loop = np.array([[-0.5, 0.0], [0.0, 0.3], [-0.5, 0.0]])  # back to the point it left: (0.5, 0) is 1 from any end
    assert curve_boundary_error([loop], poles) == pytest.approx(1.0)
    assert extract_curve_2d(current, resolution=127, delta=0.0, method="level_set") == []
    with pytest.raises(ValueError, match="method"):
        extract_curve_2d(current, method="magic")


def test_good_runs_split_a_polyline_and_keep_a_closed_ones_run_through_its_start_whole():
    from deepcurrents.eval.meshing.curve_2d import good_runs

    square = np.array([[0, 0], [1, 0], [1, 1], [0, 1], [0, 0]], dtype=float)  # closed: 4 segments
    open_line = square[:4]  # the same points, not closed: 3 segments
    pieces = good_runs(open_line, np.array([True, False, True]))
    assert [p.tolist() for p in pieces] == [[[0, 0], [1, 0]], [[1, 1], [0, 1]]]
    # closed, the segment (1,0)→(1,1) dropped: the good run goes (1,1) → (0,1) → (0,0) → (1,0), through the start
    pieces = good_runs(square, np.array([True, False, True, True]))
    assert [p.tolist() for p in pieces] == [[[1, 1], [0, 1], [0, 0], [1, 0]]]
    assert good_runs(square, np.zeros(4, bool)) == []
    assert len(good_runs(square, np.ones(4, bool))) == 1


def test_the_phase_sums_the_solid_angle_in_float64():
    """φ = f/(2·alpha_scale) + Ω/2 with Ω in float64 (meshing.grid_angle.phase_from_f): summed in float32, the
    Borromean rings' grid mesh gained extra sheets (1.4433 → 1.6782, README Fig. 4), though float32 Ω is within
    2.7e-3 rad; checked against the float64 closed form and the float32 one at points around the rings."""
    from deepcurrents.eval.meshing.grid_angle import phase_from_f
    from deepcurrents.geometry import borromean_rings
    from deepcurrents.geometry.biot_savart import solid_angle

    loops = [torch.as_tensor(lp, dtype=torch.float32) for lp in borromean_rings()]

    class Rings:  # what phase_from_f reads of a current
        alpha_scale = 1e-3

    Rings.loops = loops
    x = torch.rand(4000, 3, generator=torch.Generator().manual_seed(0)) * 1.6 - 0.8
    f = torch.rand(4000, generator=torch.Generator().manual_seed(1)) * 1e-2
    phase = phase_from_f(Rings(), x, f)
    exact = f.double() / 2e-3 + 0.5 * solid_angle(x.double(), [lp.double() for lp in loops])
    assert phase.dtype == torch.float64
    assert float((phase - exact).abs().max()) < 1e-9
    single = f.double() / 2e-3 + 0.5 * solid_angle(x, loops).double()
    assert float((single - exact).abs().max()) > 1e-6  # float32 would not pass the line above


class TiltedSealedCup(SealedCup):
    """The sealed cup with f + tilt·cos θ·b, b a Gaussian bump of width 0.15 around the rim: f along Γ runs
    from s − tilt to s + tilt (s, the mean over Γ, stays the cup's 1/2), so near θ = 0 and π the one level
    f = s passes about 0.06 off Γ, beyond the tube (a family's wrist whose f varies along it); |tilt·b| < 1/2
    keeps f = s off the rest of the box."""

    def __init__(self, tilt=0.45, **kwargs):
        super().__init__(width=0.03, **kwargs)
        self.tilt = tilt

    def f(self, x):
        rho = x[:, :2].norm(dim=-1)
        bump = torch.exp(-((rho - self.radius) ** 2 + x[:, 2] ** 2) / 0.15**2)
        return super().f(x) + self.tilt * x[:, 0] / rho.clamp_min(1e-6) * bump


def test_a_level_that_follows_f_along_gamma_closes_what_one_level_leaves_open():
    """level_blend = R: the level set reaches Γ where f varies along it, and beyond R + a voxel the mesh is the
    paper's one-level mesh vertex for vertex; the blended level's offset is f − s on Γ, 0 beyond R and its
    gradient is its finite difference."""
    from deepcurrents.eval.meshing.level_set import BoundaryLevelOffset, f_on_boundary

    cup, radius = TiltedSealedCup(), 0.1
    gamma = cup.loops[0].double().numpy()
    bounds = np.array([[-0.45, -0.45, -0.15], [0.45, 0.45, 0.7]])
    one = extract_surface(cup, resolution=40, bounds=bounds, method="level_set")
    assert one.zipped_loops == 0 and boundary_error(one.mesh, [gamma]) > 0.04  # the tube cut leaves it open
    blended = extract_surface(cup, resolution=40, bounds=bounds, method="level_set", level_blend=radius)
    mesh = blended.mesh
    assert blended.zipped_loops == 1 and boundary_error(mesh, [gamma]) < 1e-6
    assert len(mesh.split(only_watertight=False)) == 1 and mesh.is_winding_consistent
    voxel = 0.9 / 40

    def far(m):  # the cup beyond R + 2 voxels of Γ (not the cap below it, which the one level keeps)
        d = np.min(np.linalg.norm(m.vertices[:, None] - gamma[None], axis=-1), axis=1)
        return m.vertices[(d > radius + 2 * voxel) & (m.vertices[:, 2] > 0)]

    a, b = far(one.mesh), far(mesh)
    assert len(a) > 500 and len(a) == len(b)
    assert np.abs(np.sort(a, axis=0) - np.sort(b, axis=0)).max() < 1e-9

    points, f_gamma = f_on_boundary(cup, [gamma], 0.005)
    level = float(f_gamma.mean())
    assert level == pytest.approx(0.5, abs=1e-3)
    offset = BoundaryLevelOffset(points, f_gamma, level, radius)
    on = torch.as_tensor(circle(cup.radius, n=40), dtype=torch.float32)
    assert torch.allclose(offset(on), cup.f(on) - level, atol=0.01)  # the softmax's average over ±R/4
    assert (offset(on * (1 + (radius + 1e-3) / cup.radius)) == 0).all() and (offset(on * 3) == 0).all()
    x = (on * (1 + 0.4 * radius / cup.radius)).double().requires_grad_(True)
    offset64 = BoundaryLevelOffset(points, f_gamma, level, radius)  # float32 Γ, float64 queries
    (grad,) = torch.autograd.grad(offset64(x).sum(), x)
    h = 1e-6
    for k in range(3):
        e = torch.zeros(3, dtype=torch.float64)
        e[k] = h
        fd = (offset64(x.detach() + e) - offset64(x.detach() - e)) / (2 * h)
        assert torch.allclose(grad[:, k], fd, atol=1e-6)


def test_grid_shape_counts_nodes_and_refuses_a_grid_larger_than_memory(monkeypatch):
    """A 1 × 0.5 × 0.25 box at 4 cells along its longest side: voxel 0.25, 5 × 3 × 2 nodes (by hand). With
    ``NODE_BYTES`` a node, the check refuses in one sentence naming the key once the nodes outgrow the memory
    available, and does not check where that cannot be read."""
    import deepcurrents.eval.device as device
    import deepcurrents.eval.meshing.surface as surface
    from deepcurrents.errors import ConfigError

    bounds = np.array([[0.0, 0.0, 0.0], [1.0, 0.5, 0.25]])
    monkeypatch.setattr(device, "available_memory", lambda: 30 * surface.NODE_BYTES)
    assert surface.grid_shape(bounds, 4) == ((5, 3, 2), 0.25)  # 30 nodes: just fits
    monkeypatch.setattr(device, "available_memory", lambda: 29 * surface.NODE_BYTES)
    with pytest.raises(ConfigError, match=r"^evaluation\.mesh\.resolution=4 asks for a 5×3×2 meshing grid") as info:
        surface.grid_shape(bounds, 4, "evaluation.mesh.resolution")
    assert "\n" not in str(info.value)
    monkeypatch.setattr(device, "available_memory", lambda: None)
    assert surface.grid_shape(bounds, 400)[0] == (401, 201, 101)


def test_a_mesh_left_with_a_hole_is_said(monkeypatch, caplog):
    """A mesh whose border was closed onto Γ but keeps another border (a hole: a sheet thinner than the cells
    between two nodes) is said, with a finer resolution; a closed disk is not."""
    import logging

    from test_render import AnalyticDisk

    from deepcurrents.eval.meshing import surface

    monkeypatch.setitem(METHODS, "plane", PlaneMethod)
    disk = AnalyticDisk(radius=0.5, normal=tuple(PlaneMethod.normal.double().numpy()))
    with caplog.at_level(logging.WARNING):
        extract_surface(disk, resolution=40, method="plane")
    assert "hole" not in caplog.text
    # an annulus 0.2 < r < 0.5 about the circle r = 0.5: its inner border is 0.3 from Γ
    n = 64
    t = 2 * np.pi * np.arange(n) / n
    ring = lambda r: np.stack([r * np.cos(t), r * np.sin(t), 0 * t], -1)  # noqa: E731
    i = np.arange(n)
    j = (i + 1) % n
    faces = np.concatenate([np.stack([i, j, n + j], 1), np.stack([i, n + j, n + i], 1)])
    annulus = trimesh.Trimesh(np.concatenate([ring(0.2), ring(0.5)]), faces, process=False)
    box = np.array([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
    with caplog.at_level(logging.WARNING):
        surface._say_open_border(annulus, [ring(0.5)], 0.04, 0.03, box, "phase", "resolution", 64)
    assert "The mesh has a border up to 0.3 from Γ (64 of its 128 border edges" in caplog.text
    assert "resolution=96 or more" in caplog.text and "box" not in caplog.text.replace("meshed box):", "")
    caplog.clear()
    with caplog.at_level(logging.WARNING):  # a level set's hole: no word of the phase
        surface._say_open_border(annulus, [ring(0.5)], 0.04, 0.03, box, "level_set", "resolution", 64)
    assert "a hole or a tear." in caplog.text and "phase" not in caplog.text
    # a square sheet cut by its meshed box (a family member in the family's cube): widen the box, not the grid
    u = np.linspace(-0.6, 0.6, 13)
    gx, gy = np.meshgrid(u, u, indexing="ij")
    k = np.arange(12 * 13).reshape(12, 13)[:, :12].ravel()
    sheet = trimesh.Trimesh(np.stack([gx.ravel(), gy.ravel(), 0 * gx.ravel()], -1),
                            np.concatenate([np.stack([k, k + 13, k + 14], 1), np.stack([k, k + 14, k + 1], 1)]))
    caplog.clear()
    with caplog.at_level(logging.WARNING):
        surface._say_open_border(sheet, [ring(0.5)], 0.04, 0.03, np.array([[-0.6, -0.6, -0.1], [0.6, 0.6, 0.1]]),
                                 "phase", "resolution", 64)
    assert "The meshed box cuts the surface" in caplog.text and "hole" not in caplog.text


def test_aliased_edges_are_the_turns_of_more_than_half_a_turn_between_nodes():
    """By hand: f/2a rising by 2π over one edge (a jump thinner than a cell) is aliased whatever Ω does, the same
    rise over four edges is not; NaN (interpolated) nodes give no edge."""
    from deepcurrents.eval.meshing.grid_angle import aliased_edges

    half_f = np.zeros((6, 3, 3))
    half_f[3:] = 2 * np.pi  # a jump between the nodes 2 and 3 along axis 0
    omega_half = np.full_like(half_f, 0.7)
    phase = np.mod(half_f + omega_half, 2 * np.pi)  # φ = f/2a + Ω/2 (mod 2π): the same at both ends of the jump
    edges = aliased_edges(phase, half_f)
    assert len(edges) == 9 and (edges[:, 0, 0] == 2).all() and (edges[:, 1, 0] == 3).all()
    assert (edges[:, 0, 1:] == edges[:, 1, 1:]).all()
    ramp = np.broadcast_to(np.linspace(0, 2 * np.pi, 6)[:, None, None], (6, 3, 3)).copy()  # 0.4π an edge
    assert len(aliased_edges(np.mod(ramp + omega_half, 2 * np.pi), ramp)) == 0
    half_f[2:4] = np.nan
    assert len(aliased_edges(np.mod(half_f + 0.7, 2 * np.pi), half_f)) == 0


def test_a_grid_that_aliases_the_phase_away_from_gamma_is_meshed_finer(monkeypatch, caplog):
    """extract_surface meshes once more at 1.5× the resolution when the phase method reports aliased edges away
    from Γ (a sharpened catenoid at 128³ lost its sheet in places: README, Troubleshooting); next to Γ they are
    expected (Ω/2 turns fast) and change nothing."""
    import logging

    from deepcurrents.eval.meshing.phase import PhaseMethod

    torch.manual_seed(0)
    from deepcurrents.nn import neural_current

    current = neural_current(3, loops=[torch.tensor(circle(0.5, n=96)).float()], num_frequencies=8, width=8, depth=1)
    plain = extract_surface(current, resolution=24)
    calls = []
    sample = PhaseMethod.sample

    def reported(self, points, shape, loops, voxel, where):
        calls.append(tuple(shape))
        out = sample(self, points, shape, loops, voxel)
        self.aliased_points = np.array([where])
        return out

    for where, finer in (([0.5, 0.0, 0.01], False), ([0.0, 0.0, 0.3], True)):  # on Γ; 0.3 above the disk
        calls.clear()
        caplog.clear()
        monkeypatch.setattr(PhaseMethod, "sample", lambda self, *a, w=where: reported(self, *a, w))
        with caplog.at_level(logging.INFO):
            result = extract_surface(current, resolution=24)
        assert len(calls) == (2 if finer else 1)
        if finer:
            assert "meshed at 36 instead" in caplog.text and calls[1][0] > calls[0][0]
            monkeypatch.setattr(PhaseMethod, "sample", sample)
            assert result.mesh.area == pytest.approx(extract_surface(current, resolution=36).mesh.area, rel=1e-12)
        else:
            assert result.mesh.area == plain.mesh.area and "instead" not in caplog.text


def test_a_level_set_whose_newton_steps_drag_vertices_across_cells_is_meshed_finer(monkeypatch, caplog):
    """Level set: where Newton moves more than DRAGGED_SHARE of the marched vertices by more than half a cell onto
    f = s (f's jump thinner than the grid: spikes on a 180-s hand reconstruction at 96³), extract_surface meshes once
    more at 1.5× the resolution; the smooth cup's own vertices move less, and it meshes as before."""
    import logging

    from deepcurrents.eval.meshing.method import MeshMethod

    cup = SealedCup()
    bounds = np.array([[-0.4, -0.4, -0.12], [0.4, 0.4, 0.7]])
    with caplog.at_level(logging.INFO):
        plain = extract_surface(cup, resolution=40, bounds=bounds, method="level_set")
    assert "instead" not in caplog.text
    newton, calls = MeshMethod.newton, []

    def dragging(self, verts, max_step, steps):  # the first meshing's vertices land 0.6 cells away
        calls.append(max_step)
        out = newton(self, verts, max_step, steps)
        return out + (0.6 * max_step if len(calls) == 1 else 0.0)

    monkeypatch.setattr(MeshMethod, "newton", dragging)
    caplog.clear()
    with caplog.at_level(logging.INFO):
        refined = extract_surface(cup, resolution=40, bounds=bounds, method="level_set")
    assert len(calls) == 2 and calls[1] < calls[0] and "meshed at 60 instead" in caplog.text
    monkeypatch.setattr(MeshMethod, "newton", newton)
    finer = extract_surface(cup, resolution=60, bounds=bounds, method="level_set")
    assert refined.mesh.area == pytest.approx(finer.mesh.area, rel=1e-12) and refined.mesh.area != plain.mesh.area


class FlatPlane(PlaneMethod):
    """The plane z = 0."""

    name = "flat_plane"
    normal = torch.tensor([0.0, 0.0, 1.0])


class PerforatedDisk(torch.nn.Module):
    """The current of the flat disk of radius 0.8 with two holes of radius 0.3 whose rims pass ``gap`` apart: ω = e_z
    on the plane region between the three circles, 0 elsewhere (Γ: the outer rim, the two holes' rims the other
    way)."""

    def __init__(self, gap: float):
        super().__init__()
        self.dim, self.alpha_scale = 3, 1e-3
        self.centres = [np.array([-(0.3 + gap / 2), 0.0, 0.0]), np.array([0.3 + gap / 2, 0.0, 0.0])]
        holes = [circle(0.3, n=96)[::-1] + c for c in self.centres]
        self.loops = [torch.as_tensor(lp, dtype=torch.float32) for lp in (circle(0.8, n=192), *holes)]

    def evaluate(self, x, chunk_size=1 << 15, omega=True):
        x = x.double()
        inside = x[:, :2].norm(dim=-1) < 0.8
        for c in self.centres:
            inside &= (x[:, :2] - torch.as_tensor(c[:2])).norm(dim=-1) > 0.3
        w = torch.zeros_like(x)
        w[:, 2] = inside.double() * torch.exp(-0.5 * (x[:, 2] / 0.03) ** 2)
        return (torch.zeros(len(x)), w.float()) if omega else torch.zeros(len(x))


@pytest.mark.parametrize("resolution, refine", [(144, True), (80, True), (80, False)])
def test_the_tube_stays_narrower_than_the_gap_between_two_loops(monkeypatch, caplog, resolution, refine):
    """Two holes whose rims pass 0.06 apart, less than two 0.04 tubes: cut with the whole tube, their holes joined
    into one and each rim's strip fanned across the other's. The tube is now at most 0.4 of the gap: each hole is
    zipped onto its own rim, and the mesh is the perforated disk's polygon area, manifold, with three borders. A grid
    whose 1.5 cells exceed that (80 over the box: 0.025-wide cells) is refined until they fit, or, not refined, cuts a
    tube under 1.5 cells, said. Only the two close rims get the narrower tube (``_tube_radii``)."""
    monkeypatch.setitem(METHODS, "flat_plane", FlatPlane)
    current = PerforatedDisk(gap=0.06)
    loops = [lp.double().numpy() for lp in current.loops]
    with caplog.at_level("INFO", logger="deepcurrents.eval.meshing.surface"):
        result = extract_surface(current, resolution=resolution, method="flat_plane", refine_aliased=refine,
                                 bounds=np.array([[-1, -1, -0.2], [1, 1, 0.2]]))
    if resolution == 80:
        said = ("Two loops of Γ are 0.06 apart, under 3.75 cells of the resolution=80 grid" if refine
                else "their boundary tube is 0.024, under 1.5 cells of the resolution=80 grid")
        assert said in caplog.text
    mesh = result.mesh
    assert result.zipped_loops == 3
    polygon = [0.5 * abs(np.cross(lp, np.roll(lp, -1, 0)).sum(0)[2]) for lp in loops]
    assert mesh.area == pytest.approx(polygon[0] - polygon[1] - polygon[2], rel=1e-6)
    edges = np.sort(mesh.edges, axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert counts.max() == 2 and len(border_loops(np.asarray(mesh.faces))) == 3
    assert boundary_error(mesh, loops) < 1e-6


def test_only_the_loops_close_to_another_get_a_narrower_tube_and_a_grid_is_refined_at_most_twice():
    from deepcurrents.eval.meshing.surface import MeshSettings, _resolution_for_gap, _tube_radii

    settings = MeshSettings(resolution=100, boundary_tube=0.04, method="level_set")
    # loop gaps: the rim far from the two holes, the holes 0.06 apart (0.4 × 0.06 = 0.024 ≥ 1.5 cells of 0.01)
    tubes = _tube_radii(settings, 0.01, np.array([0.3, 0.06, 0.06]), None)
    np.testing.assert_allclose(tubes, [0.04, 0.024, 0.024])
    # two loops under half a cell apart (they touch at the grid's scale) keep the whole tube
    np.testing.assert_allclose(_tube_radii(settings, 0.01, np.array([0.3, 0.01, 0.01]), set()), [0.04] * 3)
    bounds = np.array([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])
    assert _resolution_for_gap(bounds, settings, 0.02, 0.06) == 125  # 1.5 cells of 0.016 fit in 0.024
    assert _resolution_for_gap(bounds, settings, 0.02, 0.02) == 200  # more would be needed: twice, not more
    assert _resolution_for_gap(bounds, settings, 0.02, 0.3) is None


def test_a_closed_piece_on_the_target_is_kept_a_bubble_off_it_dropped():
    """A reconstruction's cavity that the level set pinched off (a mouth behind thin lips) is a closed piece lying on
    the target: with ``near`` it is kept, while a bubble off the target is still dropped."""
    from deepcurrents.eval.meshing.surface import _drop_closed_components

    cavity = trimesh.creation.icosphere(subdivisions=2, radius=0.2)
    bubble = trimesh.Trimesh(cavity.vertices * 0.5 + [0.0, 0.0, 0.6], cavity.faces)
    target = trimesh.creation.icosphere(subdivisions=4, radius=0.2)  # the cavity's own surface, finer
    verts = np.concatenate([cavity.vertices, bubble.vertices])
    faces = np.concatenate([cavity.faces, bubble.faces + len(cavity.vertices)])
    kept, dropped = _drop_closed_components(verts, faces, (np.asarray(target.vertices), np.asarray(target.faces)),
                                            within=0.01)
    assert len(kept) == len(cavity.faces) and dropped == pytest.approx(bubble.area, rel=1e-12)
    _, dropped_both = _drop_closed_components(verts, faces)
    assert dropped_both == pytest.approx(cavity.area + bubble.area, rel=1e-12)


def test_weak_caps_across_an_opening_are_dropped_weak_patches_inside_kept():
    """An open cylinder (Γ: its two rims) whose level set also spans the bottom opening with a cap: the cap carries a
    tenth of the wall's |ω| and reaches the tube about the bottom rim, so it is dropped; a weak patch in the middle of
    the wall (a thin fingertip's) reaches no tube and is kept, as is everything with weak_share 0."""
    from deepcurrents.eval.meshing.surface import _drop_weak_caps

    wall = trimesh.creation.cylinder(radius=0.3, height=0.6, sections=48)
    wall = wall.subdivide().subdivide()
    normals = np.abs(wall.face_normals[:, 2])
    sides = normals < 0.5
    cap = wall.triangles_center[:, 2] < -0.29
    faces = np.asarray(wall.faces)[sides | cap]
    centres = wall.triangles_center[sides | cap]
    is_cap = cap[sides | cap]
    strength = np.where(is_cap, 0.1, 1.0)
    patch = (np.abs(centres[:, 2]) < 0.05) & (centres[:, 0] > 0.25)
    strength[patch] = 0.1
    angles = np.linspace(0, 2 * np.pi, 48, endpoint=False)
    rims = [np.stack([0.3 * np.cos(angles), 0.3 * np.sin(angles), np.full(48, z)], 1) for z in (-0.3, 0.3)]
    verts = np.asarray(wall.vertices)
    kept = _drop_weak_caps(verts, faces, strength, rims, np.array([0.03, 0.03]), 0.01, 0.5)
    assert len(kept) == len(faces) - is_cap.sum()
    kept_rows = {tuple(f) for f in kept}
    assert all(tuple(f) in kept_rows for f in faces[patch]) and patch.any()
    assert not any(tuple(f) in kept_rows for f in faces[is_cap])
    assert len(_drop_weak_caps(verts, faces, np.ones(len(faces)), rims, np.array([0.03, 0.03]), 0.01, 0.5)) \
        == len(faces)
