"""Target geometry for reconstruction: closest points, normals, the metric, boundary weighting, surface
samples, the surface loss's sign and margin, and mesh boundary loops — against brute force and hand values."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

from deepcurrents.data.targets import (
    MeshTarget,
    PointCloudTarget,
    boundary_weights,
    closest_points_on_mesh,
    distance_to_loops,
    mesh_boundary_loops,
    reconstruction_sample,
    sample_mesh_surface,
)
from deepcurrents.geometry import solid_angle
from deepcurrents.losses import surface_loss


def bumpy_patch(n: int = 6, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """An open grid patch over [-0.5, 0.5]^2, z bumped at random: 2(n−1)^2 faces, normals ~ +z."""
    rng = np.random.default_rng(seed)
    g = np.linspace(-0.5, 0.5, n)
    xx, yy = np.meshgrid(g, g, indexing="ij")
    v = np.stack([xx.ravel(), yy.ravel(), 0.08 * rng.standard_normal(n * n)], 1)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    f = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return v, f


def flat_disk(n: int = 32, radius: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """A fan-triangulated disk in the xy-plane, faces counter-clockwise seen from +z (normals +z)."""
    t = 2 * np.pi * np.arange(n) / n
    v = np.concatenate([[[0.0, 0.0, 0.0]], np.stack([radius * np.cos(t), radius * np.sin(t), 0 * t], 1)])
    f = np.stack([np.zeros(n, int), 1 + np.arange(n), 1 + (np.arange(n) + 1) % n], 1)
    return v, f


def brute_closest_on_triangles(p: np.ndarray, v: np.ndarray, f: np.ndarray):
    """Closest point of each point on each triangle by exhaustion: the plane projection when it falls
    inside, else the best of the three edges. → distances (N, F), points (N, F, 3)."""
    a, b, c = (v[f[:, k]][None] for k in range(3))  # (1, F, 3)
    q = p[:, None, :]
    n = np.cross(b - a, c - a)
    n = n / np.linalg.norm(n, axis=-1, keepdims=True)
    proj = q - ((q - a) * n).sum(-1, keepdims=True) * n

    def inside(x):
        s = [((np.cross(e1 - e0, x - e0)) * n).sum(-1) for e0, e1 in ((a, b), (b, c), (c, a))]
        return (s[0] >= 0) & (s[1] >= 0) & (s[2] >= 0)

    def on_segment(e0, e1):
        t = np.clip(((q - e0) * (e1 - e0)).sum(-1) / ((e1 - e0) ** 2).sum(-1), 0, 1)[..., None]
        return e0 + t * (e1 - e0)

    edges = ((a, b), (b, c), (c, a))
    cands = [np.where(inside(proj)[..., None], proj, np.inf)] + [on_segment(*e) for e in edges]
    cands = np.stack(cands, 0)  # (4, N, F, 3)
    d = np.linalg.norm(np.nan_to_num(cands - q[None], nan=np.inf, posinf=np.inf), axis=-1)
    best = d.argmin(0)
    dist = np.take_along_axis(d, best[None], 0)[0]
    pts = np.take_along_axis(cands, best[None, ..., None], 0)[0]
    return dist, pts


def brute_segments_distance(p: np.ndarray, loops: list[np.ndarray]) -> np.ndarray:
    e0 = np.concatenate(loops)[None]
    e1 = np.concatenate([np.roll(lp, -1, 0) for lp in loops])[None]
    q = p[:, None]
    t = np.clip(((q - e0) * (e1 - e0)).sum(-1) / ((e1 - e0) ** 2).sum(-1), 0, 1)[..., None]
    return np.linalg.norm(q - (e0 + t * (e1 - e0)), axis=-1).min(1)


def test_closest_points_normals_and_metric_match_brute_force():
    v, f = bumpy_patch()
    rng = np.random.default_rng(1)
    x = rng.uniform(-1, 1, (300, 3))
    d_all, p_all = brute_closest_on_triangles(x, v, f)
    best = d_all.argmin(1)
    d_true = d_all.min(1)
    sq, face, pts = closest_points_on_mesh(x, v, f)
    np.testing.assert_allclose(np.sqrt(sq), d_true, atol=1e-9)
    np.testing.assert_allclose(pts, p_all[np.arange(len(x)), best], atol=1e-9)

    target = MeshTarget(v, f)
    near = target.closest(x)
    np.testing.assert_allclose(near.point, p_all[np.arange(len(x)), best], atol=1e-9)
    # normals: where one face is strictly closest, it is that face's right-hand normal
    tri = v[f[best]]
    n_true = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n_true /= np.linalg.norm(n_true, axis=1, keepdims=True)
    second = np.sort(d_all, 1)[:, 1]
    unique = second > d_true + 1e-6
    assert unique.sum() > 50
    np.testing.assert_allclose(near.normal[unique], n_true[unique], atol=1e-9)
    # on Γ exactly when Γ is as close as Σ (Γ ⊂ Σ)
    d_gamma = brute_segments_distance(x, mesh_boundary_loops(v, f))
    on_true = d_gamma <= d_true + 1e-9
    assert 30 < on_true.sum() < len(x) - 30
    np.testing.assert_array_equal(near.on_boundary, on_true)

    # the metric: B = w (I − n nᵀ) off Γ, w I on Γ
    gen = torch.Generator().manual_seed(0)
    batch = reconstruction_sample(v, f, None, 400, 0, gen, boundary_weighting=False, surface_loss=False)
    assert set(batch) == {"x", "metric"}
    xb = batch["x"].double().numpy()
    d_b, _ = brute_closest_on_triangles(xb, v, f)
    fb = d_b.argmin(1)
    tri = v[f[fb]]
    nb = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    nb /= np.linalg.norm(nb, axis=1, keepdims=True)
    on_b = brute_segments_distance(xb, mesh_boundary_loops(v, f)) <= d_b.min(1) + 1e-6
    expected = np.eye(3)[None] - np.where(on_b[:, None, None], 0.0, nb[:, :, None] * nb[:, None, :])
    ok = np.sort(d_b, 1)[:, 1] > d_b.min(1) + 1e-5  # skip ties between faces and float32 rounding of x
    np.testing.assert_allclose(batch["metric"].numpy()[ok], expected[ok], atol=1e-5)


def test_a_moved_target_is_the_target_of_the_moved_mesh():
    """MeshTarget.moved (an augmented copy, the family's per-step mesh) reuses the border of the faces and answers
    closest points, normals and "on Γ" as a target built from scratch on the moved vertices does."""
    v, f = bumpy_patch(seed=2)
    base = MeshTarget(v, f)
    rng = np.random.default_rng(3)
    moved_v = 1.3 * v + 0.05 * rng.standard_normal(v.shape)  # scaled and jittered: the same faces
    loops = mesh_boundary_loops(moved_v, f)
    moved, fresh = base.moved(moved_v, loops), MeshTarget(moved_v, f, loops)
    x = rng.uniform(-1, 1, (400, 3))
    a, b = moved.closest(x), fresh.closest(x)
    np.testing.assert_array_equal(a.point, b.point)
    np.testing.assert_array_equal(a.normal, b.normal)
    np.testing.assert_array_equal(a.on_boundary, b.on_boundary)
    assert 20 < a.on_boundary.sum() < len(x) - 20
    np.testing.assert_array_equal(moved.vertex_normals, fresh.vertex_normals)
    assert moved.area == fresh.area and moved.area > base.area
    np.testing.assert_array_equal(moved.loops[0], loops[0])


def test_metric_on_and_off_the_boundary_of_a_flat_patch():
    v = np.array([[-0.5, -0.5, 0], [0.5, -0.5, 0], [0.5, 0.5, 0], [-0.5, 0.5, 0]], float)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    target = MeshTarget(v, f)
    x = np.array([[0.1, 0.2, 0.3],      # above the interior: B = I − zzᵀ
                  [0.9, 0.0, 0.3],      # beyond the edge x = 0.5: closest point on Γ, B = I
                  [0.9, 0.9, -0.2],     # beyond the corner: on Γ
                  [0.5, 0.0, 0.0]])     # on the rim itself
    near = target.closest(x)
    np.testing.assert_array_equal(near.on_boundary, [False, True, True, True])
    np.testing.assert_allclose(near.point[1], [0.5, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(near.normal[0], [0, 0, 1], atol=1e-12)


def test_boundary_weighting_near_and_far_from_gamma():
    loop = np.array([[-0.5, -0.5, 0], [0.5, -0.5, 0], [0.5, 0.5, 0], [-0.5, 0.5, 0]], float)
    sigma = 0.1
    # first half weighted: on Γ, 0.1 from Γ, far from Γ; second half: weight 1 before normalisation
    x = torch.tensor([[0.5, 0.0, 0.0], [0.5, 0.0, 0.1], [0.0, 0.0, 0.9],
                      [0.5, 0.0, 0.0], [0.0, 0.0, 0.9], [0.3, 0.3, 0.3]], dtype=torch.float64)
    w = boundary_weights(x, [loop], sigma).double()
    raw = np.array([1.0, np.exp(-0.5), np.exp(-(0.5**2 + 0.9**2) / (2 * 0.01)), 1, 1, 1])
    np.testing.assert_allclose(w.numpy(), raw * len(raw) / raw.sum(), rtol=1e-6)
    assert abs(float(w.mean()) - 1.0) < 1e-6
    np.testing.assert_array_equal(boundary_weights(x, [loop], sigma, enabled=False).numpy(), np.ones(6))
    np.testing.assert_allclose(distance_to_loops(x, [loop]), brute_segments_distance(x.numpy(), [loop]),
                               atol=1e-12)


def test_surface_samples_are_uniform_by_area_and_on_the_mesh():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -3, 0]], float) * 0.3
    f = np.array([[0, 1, 2], [0, 3, 1]])  # areas 1 : 3, both normals +z
    gen = torch.Generator().manual_seed(0)
    pts, nrm = sample_mesh_surface(v, f, 20000, gen)
    frac_second = float((pts[:, 1] < 0).mean())
    assert abs(frac_second - 0.75) < 0.015  # 5 standard deviations
    sq, _, _ = closest_points_on_mesh(pts, v, f)
    assert sq.max() < 1e-20
    np.testing.assert_allclose(nrm, np.tile([0, 0, 1.0], (len(nrm), 1)), atol=1e-12)
    # barycentric uniformity inside one triangle: the mean of uniform points is the centroid
    np.testing.assert_allclose(pts[pts[:, 1] >= 0].mean(0), v[[0, 1, 2]].mean(0), atol=3e-3)


def test_surface_loss_sign_and_margin_with_the_mesh_orientation():
    v, f = flat_disk()
    loops = mesh_boundary_loops(v, f)
    gen = torch.Generator().manual_seed(0)
    batch = reconstruction_sample(v, f, loops, 16, 2000, gen)
    y, n, eps = batch["surface_points"].double(), batch["surface_normals"].double(), batch["epsilon"].double()
    assert float(eps.min()) >= 0.0199 - 1e-7 and float(eps.max()) <= 0.0201 + 1e-7
    np.testing.assert_allclose(n.numpy(), np.tile([0, 0, 1.0], (len(n), 1)), atol=1e-6)

    def loss(field):
        return float(surface_loss(field(y - eps[:, None] * n), field(y + eps[:, None] * n), margin=0.01))

    # f = −c z drops by 2cε ≈ 0.04c across the disk along n
    assert loss(lambda p: -1.0 * p[:, 2]) == 0.0
    expected = float(torch.relu(0.01 - 2 * 0.1 * eps).mean())
    assert abs(loss(lambda p: -0.1 * p[:, 2]) - expected) < 1e-12 and expected > 0.005
    assert abs(loss(lambda p: 1.0 * p[:, 2]) - float((0.01 + 2 * eps).mean())) < 1e-12
    # the ideal current's f = −alpha_scale·Ω_Γ jumps by 4π·1e-3 > δ across the disk with Γ from the mesh
    # (less within ~ε of the rim): f drops along n with the mesh's orientation, rises with the loops reversed
    gamma = [torch.as_tensor(lp) for lp in loops]
    ideal = [lambda p, g=g: -1e-3 * solid_angle(p, g) for g in (gamma, [lp.flip(0) for lp in gamma])]
    drop = [field(y - eps[:, None] * n) - field(y + eps[:, None] * n) for field in ideal]
    # (the smooth part of Ω changes by about 4π ε/R over the 2ε step, so the median drop is ~ 4π·1e-3·0.93)
    assert 0.85 < float(drop[0].median()) / (4e-3 * np.pi) < 1.0
    assert 0.85 < -float(drop[1].median()) / (4e-3 * np.pi) < 1.0
    assert loss(ideal[0]) < 5e-4 < 0.02 < loss(ideal[1])


def test_mesh_boundary_loops_follow_the_faces():
    v, f = flat_disk(n=12)
    (loop,) = mesh_boundary_loops(v, f)
    signed_area = 0.5 * np.sum(loop[:, 0] * np.roll(loop[:, 1], -1) - np.roll(loop[:, 0], -1) * loop[:, 1])
    assert signed_area > 0  # counter-clockwise seen from +z, the faces' normal
    # flipping the faces reverses the loop: consecutive rim vertices go clockwise
    (flipped,) = mesh_boundary_loops(v, f[:, ::-1].copy())
    turn = np.cross(flipped[0], flipped[1])[2]
    assert turn < 0 and len(flipped) == 12
    # an annulus: outer rim counter-clockwise, inner rim clockwise (seen from +z)
    ann = trimesh.creation.annulus(r_min=0.2, r_max=0.5, height=0.1, sections=24)
    top = ann.face_normals[:, 2] > 0.99
    sub = trimesh.Trimesh(ann.vertices, ann.faces[top], process=False)
    loops = mesh_boundary_loops(sub.vertices, sub.faces)
    assert len(loops) == 2
    areas = sorted(0.5 * np.sum(lp[:, 0] * np.roll(lp[:, 1], -1) - np.roll(lp[:, 0], -1) * lp[:, 1])
                   for lp in loops)
    assert areas[0] < 0 < areas[1] and abs(areas[1]) > abs(areas[0])
    # a closed mesh has none
    ico = trimesh.creation.icosphere(1)
    assert mesh_boundary_loops(ico.vertices, ico.faces) == []


def test_point_cloud_target_matches_brute_force():
    v, f = bumpy_patch(n=8)
    gen = torch.Generator().manual_seed(3)
    pts, nrm = sample_mesh_surface(v, f, 3000, gen)
    loops = mesh_boundary_loops(v, f)
    target = PointCloudTarget(pts, nrm, loops)
    x = np.random.default_rng(0).uniform(-1, 1, (200, 3))
    near = target.closest(x)
    brute = np.linalg.norm(x[:, None] - pts[None], axis=-1).argmin(1)
    np.testing.assert_allclose(near.point, pts[brute])
    np.testing.assert_allclose(near.normal, nrm[brute] / np.linalg.norm(nrm[brute], axis=1, keepdims=True))
    # beyond the rim (far outside the patch, level with it) the closest part of Σ is Γ; above the middle not
    far = target.closest(np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 0.4]]))
    np.testing.assert_array_equal(far.on_boundary, [True, False])
    batch = target.sample(64, 32, gen)
    assert batch["metric"].shape == (64, 3, 3) and batch["surface_points"].shape == (32, 3)


def test_sampling_is_reproducible_and_accepts_torch_inputs():
    v, f = bumpy_patch()
    a = reconstruction_sample(torch.as_tensor(v), torch.as_tensor(f), None, 100, 50,
                              torch.Generator().manual_seed(5))
    b = reconstruction_sample(v, f, None, 100, 50, torch.Generator().manual_seed(5))
    for key in a:
        assert torch.equal(a[key], b[key])
    assert all(t.dtype == torch.float32 for t in a.values())


@pytest.mark.parametrize("weighting", [True, False])
def test_weighting_flag_changes_only_weights(weighting):
    v, f = bumpy_patch()
    batch = reconstruction_sample(v, f, None, 200, 10, torch.Generator().manual_seed(1),
                                  boundary_weighting=weighting)
    # every metric is w (projector or identity): its largest eigenvalue is w
    w = torch.linalg.eigvalsh(batch["metric"].double())[:, -1]
    assert (w.mean() - 1.0).abs() < 1e-5
    assert bool((w.std() > 1e-3) == weighting)


def test_metric_band_makes_the_metric_euclidean_away_from_the_surface():
    # a flat square in z = 0: above its interior the paper's metric is w (I − zzᵀ) at any height; with a band
    # of 0.05 it stays so up to height 0.05 and is w I beyond (the target current vanishes there)
    v = np.array([[-0.5, -0.5, 0], [0.5, -0.5, 0], [0.5, 0.5, 0], [-0.5, 0.5, 0]], float)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    gen = torch.Generator().manual_seed(3)
    paper = reconstruction_sample(v, f, None, 4000, 0, gen, boundary_weighting=False, surface_loss=False)
    gen = torch.Generator().manual_seed(3)  # the same samples
    band = reconstruction_sample(v, f, None, 4000, 0, gen, boundary_weighting=False, surface_loss=False,
                                 metric_band=0.05)
    x = band["x"].double()
    assert torch.equal(paper["x"], band["x"])
    inside = (x[:, :2].abs() < 0.5).all(1)
    projector = torch.eye(3, dtype=torch.float64) - torch.tensor([0, 0, 1.0]).outer(torch.tensor([0, 0, 1.0]))
    near, far = inside & (x[:, 2].abs() < 0.049), inside & (x[:, 2].abs() > 0.051)
    assert near.sum() > 5 and far.sum() > 500
    torch.testing.assert_close(paper["metric"][inside].double(), projector.expand(int(inside.sum()), 3, 3))
    torch.testing.assert_close(band["metric"][near].double(), projector.expand(int(near.sum()), 3, 3))
    eye = torch.eye(3, dtype=torch.float64)
    torch.testing.assert_close(band["metric"][far].double(), eye.expand(int(far.sum()), 3, 3))
    # beyond the square's rim the closest point is on Γ: w I in both
    torch.testing.assert_close(band["metric"][~inside], paper["metric"][~inside])


def slab_faces(thickness: float, n: int = 9) -> tuple[np.ndarray, np.ndarray]:
    """A thin slab's two faces: the square [-0.5, 0.5]^2 at z = 0 (normal +z) and again at z = −thickness
    (normal −z), as the two sides of a finger; open, 4(n−1)^2 faces."""
    v, f = flat_patch(n)
    lower = v.copy()
    lower[:, 2] = -thickness
    return np.concatenate([v, lower]), np.concatenate([f, f[:, ::-1] + len(v)])


def flat_patch(n: int) -> tuple[np.ndarray, np.ndarray]:
    """The flat grid patch of ``bumpy_patch`` (normals +z) without its bumps."""
    v, f = bumpy_patch(n)
    v[:, 2] = 0.0
    return v, f


@pytest.mark.parametrize(("thickness", "expected"), [(0.06, 0.04), (0.03, 0.04 * 0.25 ** (2 / 3)), (0.012, 0.01)])
def test_clear_surface_epsilon_keeps_the_offsets_on_their_own_side_of_a_thin_slab(thickness, expected):
    """A range [0.01, 0.04] tried in the steps 0.04, 0.0252, 0.0159, 0.01: on the upper face of a slab of
    thickness t, y − εn lies between the faces while ε < t, and there it is clear while also t − ε ≥ 0.25 ε, i.e.
    ε ≤ 0.8 t (hand-computed: t = 0.06 → 0.04; t = 0.03 → 0.0159; t = 0.012: no step but the floor). Past the
    lower face it is on that face's outer side and never clear. A single face keeps 0.04 everywhere."""
    from deepcurrents.data.targets import clear_surface_epsilon, target_sample

    v, f = slab_faces(thickness)
    target = MeshTarget(v, f)
    y = np.array([[x, yy, 0.0] for x in (-0.2, 0.0, 0.15) for yy in (-0.1, 0.2)])
    n = np.tile([0.0, 0.0, 1.0], (len(y), 1))
    np.testing.assert_allclose(clear_surface_epsilon(target, y, n, 0.01, 0.04), expected, rtol=1e-12)
    # from the lower face (normal −z) the slab is the same
    np.testing.assert_allclose(clear_surface_epsilon(target, y * [1, 1, 0] - [0, 0, thickness], -n, 0.01, 0.04),
                               expected, rtol=1e-12)
    single = MeshTarget(*flat_patch(9))
    np.testing.assert_allclose(clear_surface_epsilon(single, y, n, 0.01, 0.04), 0.04)
    # in a batch: each sample's ε is one of the steps (± 0.5 %), a fixed ε is the paper's U[0.995 ε, 1.005 ε]
    gen = torch.Generator().manual_seed(0)
    eps = target_sample(target, 8, 300, gen, surface_epsilon=(0.01, 0.04))["epsilon"].numpy()
    steps = np.geomspace(0.04, 0.01, 4)
    nearest = steps[np.abs(eps[:, None] / steps - 1).argmin(1)]
    assert np.all(np.abs(eps / nearest - 1) <= 0.005 + 1e-6)
    if thickness > 0.05:  # away from the rims, the whole upper and lower faces are clear at 0.04
        assert np.mean(nearest == 0.04) > 0.8
    fixed = target_sample(target, 8, 300, gen, surface_epsilon=0.03)["epsilon"].numpy()
    assert fixed.min() >= 0.03 * 0.995 * (1 - 1e-6) and fixed.max() <= 0.03 * 1.005 * (1 + 1e-6)
