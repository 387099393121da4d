"""Biot–Savart fields, solid angles and boundary curves against independent truth."""

import logging
import math

import numpy as np
import pytest
import torch

from deepcurrents.geometry import (
    BoundaryError,
    biot_savart,
    biot_savart_2d,
    borromean_rings,
    circle,
    hopf_link,
    load_boundary,
    read_curve_file,
    solid_angle,
    trefoil,
)
from deepcurrents.geometry.curves import write_curve_file
from deepcurrents.geometry.polyline import (
    polyline_hausdorff,
    project_to_segments,
    sample_tube,
    segment_distance,
    tube_density,
)


def quadrature_biot_savart(points, loop, per_segment=400):
    """∮ dℓ × r / |r|³ with r = x − ℓ (Gauss–Legendre per segment), the definition the closed form solves."""
    nodes, weights = np.polynomial.legendre.leggauss(per_segment)
    s, w = (nodes + 1) / 2, weights / 2
    a, b = loop, np.roll(loop, -1, 0)
    out = np.zeros_like(points)
    for p0, p1 in zip(a, b, strict=True):
        seg = p1 - p0
        q = p0 + s[:, None] * seg  # (K, 3)
        r = points[:, None, :] - q[None]  # from the curve to x
        integrand = np.cross(np.broadcast_to(seg, r.shape), r) / np.linalg.norm(r, axis=-1, keepdims=True) ** 3
        out += (w[None, :, None] * integrand).sum(1)
    return out


def random_loop(rng, n=7):
    t = np.sort(rng.uniform(0, 2 * np.pi, n))
    r = rng.uniform(0.3, 0.6, n)
    return np.stack([r * np.cos(t), r * np.sin(t), rng.uniform(-0.2, 0.2, n)], 1)


def test_biot_savart_matches_quadrature_on_random_curves():
    rng = np.random.default_rng(1)
    loop = random_loop(rng)
    pts = rng.uniform(-0.9, 0.9, (50, 3))
    closed = biot_savart(torch.tensor(pts), [torch.tensor(loop)]).numpy()
    # sign convention: α = ∮ dℓ × r/|r|³ with r from x to the curve == −(the same with r from curve to x)
    quad = -quadrature_biot_savart(pts, loop)
    np.testing.assert_allclose(closed, quad, rtol=1e-6, atol=1e-8)


def test_circle_centre_value():
    a = biot_savart(torch.zeros(1, 3, dtype=torch.float64), [torch.tensor(circle(1.0, n=4000))])
    np.testing.assert_allclose(a.numpy(), [[0.0, 0.0, -2 * math.pi]], atol=2e-5)


def test_axis_matches_gradient_of_exact_solid_angle():
    R, loop = 0.7, torch.tensor(circle(0.7, n=20000))
    z = np.array([0.1, 0.35, 0.8])
    h = 1e-5

    def omega(z):  # the exact solid angle of the disk seen from the axis
        return 2 * np.pi * (1 - z / np.sqrt(z * z + R * R))

    fd = (omega(z + h) - omega(z - h)) / (2 * h)
    pts = torch.tensor(np.stack([np.zeros(3), np.zeros(3), z], 1))
    a = biot_savart(pts, [loop]).numpy()
    np.testing.assert_allclose(a[:, 2], fd, rtol=1e-6)
    np.testing.assert_allclose(a[:, :2], 0.0, atol=1e-8)
    np.testing.assert_allclose(solid_angle(pts, [loop]).numpy(), omega(z), rtol=1e-6)


def test_alpha_is_gradient_of_solid_angle_and_curl_free():
    rng = np.random.default_rng(2)
    loops = [torch.tensor(l) for l in trefoil(60)]
    pts = torch.tensor(rng.uniform(-0.8, 0.8, (20, 3)), requires_grad=True)
    (grad,) = torch.autograd.grad(solid_angle(pts, loops).sum(), pts)
    a = biot_savart(pts.detach(), loops)
    # away from the branch cut the solid angle is smooth and its gradient is α
    np.testing.assert_allclose(grad.numpy(), a.numpy(), rtol=1e-6, atol=1e-6)
    # curl by central differences of α
    x = pts.detach()[:5]
    h = 1e-5
    jac = torch.zeros(5, 3, 3, dtype=torch.float64)
    for j in range(3):
        e = torch.zeros(3, dtype=torch.float64)
        e[j] = h
        jac[:, :, j] = (biot_savart(x + e, loops) - biot_savart(x - e, loops)) / (2 * h)
    curl = torch.stack([jac[:, 2, 1] - jac[:, 1, 2], jac[:, 0, 2] - jac[:, 2, 0], jac[:, 1, 0] - jac[:, 0, 1]], 1)
    assert curl.abs().max() < 1e-5 * jac.abs().max()


def test_biot_savart_on_a_segments_line_gets_nothing_from_that_segment():
    """A point on the line through a side of Γ, off the side: that side's dℓ × r is zero, so α is the other sides'
    field (quadrature), with finite derivatives in the point (float32 and float64)."""
    square = np.array([[0.0, 0.0, 0.0], [0.4, 0.0, 0.0], [0.4, 0.4, 0.1], [0.0, 0.4, 0.0]])
    on_line = np.array([[0.7, 0.0, 0.0], [-0.25, 0.0, 0.0]])  # beyond either end of the first side
    quad = -quadrature_biot_savart(on_line, square)
    for dtype, rtol in ((torch.float64, 1e-9), (torch.float32, 1e-5)):
        x = torch.tensor(on_line, dtype=dtype, requires_grad=True)
        alpha = biot_savart(x, [torch.tensor(square, dtype=dtype)])
        np.testing.assert_allclose(alpha.detach().double().numpy(), quad, rtol=rtol, atol=1e-6)
        alpha.square().sum().backward()
        assert torch.isfinite(x.grad).all()


def test_biot_savart_derivatives_stay_finite_at_and_next_to_vertices_in_float32():
    """First and second derivatives in the points (gradcheck-style uses of α, e.g. curl checks) at a vertex, 1e-14
    from one (float32's rounding scale there) and at a trefoil's vertices: finite, as in float64."""
    square = torch.tensor([[0.0, 0.0, 0.0], [0.4, 0.0, 0.0], [0.4, 0.4, 0.1], [0.0, 0.4, 0.0]])
    loop = torch.tensor(trefoil()[0], dtype=torch.float32)
    near = torch.tensor([[0.0, 0.0, 0.0], [1e-14, 1e-14, 0.0], [1e-13, 0.0, 0.0], [3e-14, 3e-14, 0.0]])
    for points, curve in ((near, square), (loop[:5], loop)):
        x = points.clone().requires_grad_(True)
        (first,) = torch.autograd.grad(biot_savart(x, [curve]).square().sum(), x, create_graph=True)
        (second,) = torch.autograd.grad(first.square().sum(), x)
        assert torch.isfinite(first).all() and torch.isfinite(second).all()


def test_biot_savart_is_finite_on_the_curve_and_chunking_is_exact():
    loop = torch.tensor(circle(0.5, n=50))
    on_curve = torch.cat([loop[:5], 0.5 * (loop[:5] + loop[1:6])])  # vertices and segment midpoints
    assert torch.isfinite(biot_savart(on_curve, [loop])).all()
    pts = torch.rand(3000, 3, dtype=torch.float64) * 2 - 1
    np.testing.assert_allclose(biot_savart(pts, [loop], chunk_size=257).numpy(), biot_savart(pts, [loop]).numpy())
    assert biot_savart(pts.float(), [loop]).dtype == torch.float32


def test_biot_savart_2d_is_gradient_of_angle():
    poles = torch.tensor([[-0.5, 0.0], [0.5, 0.1]], dtype=torch.float64)
    signs = torch.tensor([-1.0, 1.0], dtype=torch.float64)
    pts = (torch.rand(30, 2, dtype=torch.float64) * 2 - 1).requires_grad_(True)
    d = pts[:, None, :] - poles[None]
    angle = (signs * torch.atan2(d[..., 1], d[..., 0])).sum(1)
    (grad,) = torch.autograd.grad(angle.sum(), pts)
    np.testing.assert_allclose(biot_savart_2d(pts.detach(), poles, signs).numpy(), grad.numpy(), rtol=1e-10)
    assert torch.isfinite(biot_savart_2d(poles, poles, signs)).all()


def test_paper_curves():
    (t,) = trefoil()
    assert t.shape == (100, 3)
    np.testing.assert_allclose(t[0], np.array([0.0, 1 - 2, 0.0]) / 6)
    h = hopf_link()
    np.testing.assert_allclose(h[0].mean(0), [-0.3, 0, 0], atol=1e-12)
    np.testing.assert_allclose(h[1][:, 1], 0.0)
    b = borromean_rings()
    assert len(b) == 3 and all(np.abs(lp).max() <= 0.6 + 1e-12 for lp in b)


def test_curve_files(tmp_path):
    obj = tmp_path / "two.obj"
    c1, c2 = circle(0.4, (0, 0, 0.2), n=8), circle(0.3, (0, 0, -0.2), n=6)
    lines = [f"v {x} {y} {z}" for x, y, z in np.concatenate([c1, c2])]
    lines += ["l " + " ".join(str(i) for i in range(1, 9)) + " 1", "l " + " ".join(str(i) for i in range(9, 15))]
    obj.write_text("\n".join(lines))
    loops = load_boundary(str(obj)).loops
    assert [len(lp) for lp in loops] == [8, 6]  # the repeated closing vertex was dropped
    txt = tmp_path / "c.txt"
    np.savetxt(txt, c1)
    np.testing.assert_allclose(read_curve_file(txt)[0], c1)
    npy = tmp_path / "c.npy"
    np.save(npy, c1)
    np.testing.assert_allclose(load_boundary(str(npy)).loops[0], c1)


def test_text_curves_take_a_header_comments_and_blank_lines_between_loops(tmp_path):
    """As spreadsheets and scripts write them: a header row of words, indented and trailing '#' comments, and a
    blank line between two loops (before: the header was 'could not convert string to float', an indented comment
    too, and the two loops became one, joined by a chord). A word row later on names its line."""
    c1, c2 = circle(0.4, (0, 0, 0.2), n=8), circle(0.3, (0, 0, -0.2), n=6)
    rows = ["x,y,z", "   # two rings"] + [f"{x},{y},{z}" for x, y, z in c1] + [""]
    rows += [f"{x} {y} {z}  # ring 2" for x, y, z in c2] + ["", ""]
    path = tmp_path / "rings.csv"
    path.write_text("\n".join(rows))
    loops = read_curve_file(path)
    assert len(loops) == 2
    np.testing.assert_allclose(loops[0], c1)
    np.testing.assert_allclose(loops[1], c2)
    path.write_text("\n".join(rows[2:6] + ["end of ring"] + rows[6:]))
    with pytest.raises(BoundaryError, match=r"line 5 \('end of ring'\) is not a row of numbers"):
        read_curve_file(path)
    # blank lines that are spacing, not separators: one loop (a stray one mid-loop, double spacing, \r\r\n line
    # ends, which read as a blank line after every row), with a byte-order mark and a header after a comment
    ring = [f"{x} {y} {z}" for x, y, z in c1]
    for text in ("\n".join(ring[:4] + [""] + ring[4:]), "\n\n".join(ring), "\r\r\n".join(ring),
                 "\ufeff# exported\nx y z\n" + "\n".join(ring)):
        path.write_bytes(text.encode("utf-8"))
        (loop,) = read_curve_file(path)
        np.testing.assert_allclose(loop, c1)


def test_a_semicolon_separated_file_names_its_first_line_and_the_separator(tmp_path):
    """Rows like `0.5;0.05;0`: the first was taken for a header (no token parses as a number), so the error named
    line 2; a header needs words."""
    path = tmp_path / "semicolon.csv"
    path.write_text("\n".join(f"{x};{y};{z}" for x, y, z in circle(0.4, n=8)))
    with pytest.raises(BoundaryError, match=r"line 1 \('0\.4;0\.0;0\.0'\) is not a row of numbers \(';' is not a "
                                            r"separator: use spaces or commas\)"):
        read_curve_file(path)


def test_blocks_read_as_one_loop_are_said(tmp_path, caplog):
    """Two half-discs, each written as its arc (closed by its chord), blank-line separated: a chord is long against
    the arc's steps, so the blocks read as one loop — silently before; now a warning says so and how to separate
    them (the probe's run meshed 0.148 against the two half-discs' 0.283)."""
    t = np.linspace(0, np.pi, 33)
    upper = np.c_[0.3 * np.cos(t), 0.3 * np.sin(t) + 0.35, np.zeros(33)]
    lower = np.c_[0.3 * np.cos(t), -0.3 * np.sin(t) - 0.35, np.zeros(33)]
    path = tmp_path / "two_d.txt"
    path.write_text("\n".join(" ".join(map(str, r)) for r in upper) + "\n\n"
                    + "\n".join(" ".join(map(str, r)) for r in lower) + "\n")
    with caplog.at_level(logging.WARNING):
        (loop,) = read_curve_file(path)
    assert len(loop) == 66 and "2 blank-line-separated blocks are read as ONE loop, because block 1" in caplog.text


def test_a_curve_written_open_is_said_to_be_closed_by_its_last_step(tmp_path, caplog):
    """A half-circle arc written as a polyline (.txt, .npy, one .obj 'l' element, .obj vertices only) is closed by its
    diameter, as every loop is: silently before, now with a warning naming the loop; the closed ring (written with or
    without its first vertex repeated) and a pentagon with one long side say nothing."""
    t = np.linspace(0, np.pi, 17)
    arc = np.c_[0.4 * np.cos(t), 0.4 * np.sin(t), np.zeros(17)]
    ring = circle(0.4, n=16)
    house = np.array([[0, 0, 0], [0.5, 0, 0], [0.5, 0.3, 0], [0.25, 0.5, 0], [0, 0.3, 0]], dtype=float)
    np.savetxt(tmp_path / "arc.txt", arc)
    np.save(tmp_path / "arc.npy", arc)
    write_curve_file(tmp_path / "arc.obj", [arc])
    (tmp_path / "arc_vertices.obj").write_text("".join(f"v {x} {y} {z}\n" for x, y, z in arc))
    write_curve_file(tmp_path / "ring.obj", [ring])
    np.savetxt(tmp_path / "ring_repeated.txt", np.concatenate([ring, ring[:1]]))
    np.savetxt(tmp_path / "house.txt", np.roll(house, -1, axis=0))  # its long side (0.5) closes it; others 0.3–0.32
    for name, open_ in (("arc.txt", True), ("arc.npy", True), ("arc.obj", True), ("arc_vertices.obj", True),
                        ("ring.obj", False), ("ring_repeated.txt", False), ("house.txt", False)):
        caplog.clear()
        with caplog.at_level(logging.WARNING):
            (loop,) = read_curve_file(tmp_path / name)
        said = "loop 0 does not come back to its start (its last vertex is 0.8 from its first"
        assert (said in caplog.text) == open_, name
        assert len(loop) == (17 if open_ else 5 if name == "house.txt" else 16)


def test_a_curve_drawn_twice_is_warned_about(tmp_path, caplog):
    """A loop that runs round twice, or the same loop listed twice, makes α double the curve (accepted before
    without a word; the probe's runs left the loop open); two different rings say nothing."""
    ring, other = circle(0.4, n=20), circle(0.3, (0, 0, 0.2), n=20)
    np.savetxt(tmp_path / "round_twice.txt", np.concatenate([ring, ring]))
    write_curve_file(tmp_path / "listed_twice.obj", [ring, ring])
    write_curve_file(tmp_path / "two_rings.obj", [ring, other])
    for name, said in (("round_twice.txt", "passes 20 of its vertices twice"),
                       ("listed_twice.obj", "loops 0 and 1 are the same curve"), ("two_rings.obj", None)):
        caplog.clear()
        with caplog.at_level(logging.WARNING):
            load_boundary(str(tmp_path / name))
        assert (said in caplog.text) if said else "twice" not in caplog.text and "same curve" not in caplog.text


def test_obj_segments_chain_whichever_way_each_is_written(tmp_path, caplog):
    """A curve written edge by edge ('l a b'), as exporters do, in shuffled order, half the edges reversed and each
    edge with its own copies of its two vertices: one loop, the 12-gon itself (in the direction of its first
    edge). Before, a reversed edge ended the chain and the file was refused as a loop of 2 vertices. A chain with
    two open ends is closed with a warning; a branching one is one sentence."""
    ring = circle(0.4, n=12)
    rng = np.random.default_rng(0)
    lines, edges = [], []
    for k in rng.permutation(12):
        a, b = ring[k], ring[(k + 1) % 12]
        if rng.random() < 0.5:
            a, b = b, a
        lines += ["v " + " ".join(repr(float(c)) for c in p) for p in (a, b)]  # exact: the copies coincide
        edges.append(f"l {len(lines) - 1} {len(lines)}")
    path = tmp_path / "edges.obj"
    path.write_text("\n".join(lines + edges) + "\n")
    (loop,) = read_curve_file(path)
    assert len(loop) == 12
    start = int(np.argmin(np.linalg.norm(ring - loop[0], axis=1)))
    step = 1 if np.allclose(loop[1], ring[(start + 1) % 12]) else -1
    np.testing.assert_allclose(loop, ring[(start + step * np.arange(12)) % 12])
    path.write_text("\n".join(lines + [e for e in edges[:-1]]) + "\n")  # one edge missing: an open chain
    assert [len(lp) for lp in read_curve_file(path)] == [12]
    assert "did not close" in caplog.text
    # written from the far end backwards (l 12 1, l 11 12, ...; the last edge missing): still the segments' way
    back = [f"v {x!r} {y!r} {z!r}" for x, y, z in ring.tolist()] + [f"l {k + 1} {k + 2}" for k in range(10, -1, -1)]
    path.write_text("\n".join(back) + "\n")
    (loop,) = read_curve_file(path)
    assert 0.5 * np.cross(loop, np.roll(loop, -1, 0)).sum(0)[2] > 0  # counter-clockwise, as ring and its edges
    # two squares that share a corner, edge by edge, and vertex copies that differ in the ninth digit: two loops
    square = [(0, 0), (1, 0), (1, 1), (0, 1), (-1, 0), (-1, -1), (0, -1)]
    rows = [f"v {0.1 * x + 1e-10 * k} {0.1 * y} 0" for k, (x, y) in enumerate(square)]
    rows += [f"v {0.1 * x} {0.1 * y} 1e-10" for x, y in square]
    rows += [f"l {a} {b + 7}" for a, b in ((1, 2), (2, 3), (3, 4), (4, 1), (1, 5), (5, 6), (6, 7), (7, 1))]
    path.write_text("\n".join(rows) + "\n")
    assert sorted(len(lp) for lp in read_curve_file(path)) == [4, 4]
    verts = "v 0 0 0\nv 0.1 0 0\nv 0 0.1 0\nv 0 0 0.1\n"
    path.write_text(verts + "l 1 2\nl 1 3\nl 1 4\n")
    with pytest.raises(BoundaryError, match="branches: 3 'l' segments meet at vertex 1"):
        read_curve_file(path)
    path.write_text(verts + "f 1 2 3\nf 1 3 4\n")  # a mesh, not a curve
    with pytest.raises(BoundaryError, match="holds a mesh"):
        read_curve_file(path)


@pytest.mark.parametrize(
    "content, message",
    [
        (None, "does not exist"),
        ("", "contains no curve vertices"),
        ("0 0 0\n1e-1 0 0\n", "at least 3"),
        ("0 0 0\n0.1 0 0\n0.2 0 0\n", "collinear"),
        ("0 0 0\nnan 0 0\n0 0.1 0\n", "NaN"),
        ("0 0 0\n1.5 0 0\n0 0.1 0\n", "outside the domain"),
        ("0 0\n1 0\n", "3 coordinates"),
    ],
)
def test_bad_curve_files_give_one_sentence(tmp_path, content, message):
    path = tmp_path / "bad.txt"
    if content is not None:
        path.write_text(content)
    with pytest.raises(BoundaryError, match=message) as info:
        load_boundary(str(path))
    assert "bad.txt" in str(info.value) and "\n" not in str(info.value)


def test_duplicate_vertices_are_dropped_with_a_warning(tmp_path, caplog):
    path = tmp_path / "dup.txt"
    loop = circle(0.5, n=6)
    np.savetxt(path, np.concatenate([loop[:3], loop[2:3], loop[3:]]))
    assert len(load_boundary(str(path)).loops[0]) == 6
    assert "duplicate" in caplog.text


def test_project_to_segments_and_hausdorff_brute_force():
    rng = np.random.default_rng(3)
    a, b = rng.uniform(-1, 1, (7, 3)), rng.uniform(-1, 1, (7, 3))
    pts = rng.uniform(-1, 1, (40, 3))
    proj = project_to_segments(torch.tensor(pts), torch.tensor(a), torch.tensor(b))
    t = np.linspace(0, 1, 20001)
    dense = a[:, None] + t[None, :, None] * (b - a)[:, None]
    brute = np.linalg.norm(pts[:, None, None] - dense[None], axis=-1).min(axis=(1, 2))
    np.testing.assert_allclose(proj.distance.numpy(), brute, atol=1e-4)
    np.testing.assert_allclose(segment_distance(pts, a, b), brute, atol=1e-4)  # libigl's tree, the same distances
    np.testing.assert_allclose(segment_distance(pts, a, b), proj.distance.numpy(), rtol=1e-12, atol=1e-14)
    # concentric squares of half-widths 1 and 0.5: the farthest points are the corners, √0.5 apart
    sq = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float)
    h = polyline_hausdorff(sq, np.roll(sq, -1, 0), 0.5 * sq, 0.5 * np.roll(sq, -1, 0), spacing=1e-3)
    assert abs(h - math.sqrt(0.5)) < 1e-3


def test_angle_2d_is_the_potential_of_the_2d_biot_savart_field():
    """∇ Σ_j s_j·angle(x − p_j) = biot_savart_2d, by central differences away from the points."""
    from deepcurrents.geometry import angle_2d, biot_savart_2d

    poles = torch.tensor([[-0.4, 0.0], [0.4, 0.1]], dtype=torch.float64)
    signs = torch.tensor([-1.0, 1.0], dtype=torch.float64)
    x = torch.tensor([[0.1, 0.5], [-0.6, -0.3], [0.7, -0.8]], dtype=torch.float64)
    h = 1e-6
    fd = torch.stack([(angle_2d(x + e, poles, signs) - angle_2d(x - e, poles, signs)) / (2 * h)
                      for e in torch.eye(2, dtype=torch.float64) * h], 1)
    assert torch.allclose(fd, biot_savart_2d(x, poles, signs), rtol=1e-7, atol=1e-9)


def test_tube_samples_have_the_density_they_report():
    """``sample_tube``'s points lie within the radius of the segment they were drawn about, and 1/q over them
    averages the tube's volume: a straight segment's cylinder exactly π ρ² L in expectation; an L-shaped
    polyline's two cylinders overlap inside the bend (q adds there), checked against the fraction of uniform
    points of a box around it that ``tube_density`` puts in the tube."""
    gen = torch.Generator().manual_seed(0)
    rho = 0.1
    a, b = torch.tensor([[0.0, 0.0, 0.0]], dtype=torch.float64), torch.tensor([[0.6, 0.8, 0.0]], dtype=torch.float64)
    x, q = sample_tube(a, b, rho, 40000, gen)
    proj = project_to_segments(x, a, b)
    assert float(proj.distance.max()) < rho and 0.0 < float(proj.t.min()) and float(proj.t.max()) < 1.0
    np.testing.assert_allclose(q.numpy(), 1.0 / (2 * math.pi * 1.0 * rho * proj.distance.numpy()), rtol=1e-9)
    inv = (1.0 / q).numpy()
    assert abs(inv.mean() - math.pi * rho**2 * 1.0) < 4 * inv.std() / math.sqrt(len(inv))

    starts = torch.tensor([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0]], dtype=torch.float64)
    ends = torch.tensor([[0.5, 0.0, 0.0], [0.5, 0.5, 0.3]], dtype=torch.float64)
    _, q = sample_tube(starts, ends, rho, 40000, gen)
    inv = (1.0 / q).numpy()
    lo, hi = torch.tensor([-0.15, -0.15, -0.15]), torch.tensor([0.65, 0.65, 0.45])
    box = lo + (hi - lo) * torch.rand(400000, 3, generator=gen, dtype=torch.float64)
    inside = (tube_density(box, starts, ends, rho) > 0).double().numpy()
    volume = float((hi - lo).prod()) * inside.mean()
    error = math.hypot(inv.std() / math.sqrt(len(inv)), float((hi - lo).prod()) * inside.std() / math.sqrt(len(box)))
    assert abs(inv.mean() - volume) < 4 * error
    assert inv.mean() < math.pi * rho**2 * (0.5 + math.hypot(0.5, 0.3))  # the overlap counted once


def test_current_keeps_its_loops_segment_table_and_follows_a_loaded_boundary():
    """NeuralCurrent.field hands biot_savart a segment table made once per dtype and device: the same α bit for bit
    as from the loops, and a state with other loops (same sizes) loaded into the current gives their α."""
    from deepcurrents.geometry import biot_savart, circle, trefoil
    from deepcurrents.nn import neural_current

    torch.manual_seed(0)
    knot = [torch.tensor(lp, dtype=torch.float32) for lp in trefoil(n=64)]
    current = neural_current(3, loops=knot, num_frequencies=4, width=8, depth=1)
    x = torch.rand(50, 3) * 2 - 1
    assert torch.equal(current.field(x), biot_savart(x, knot))
    assert torch.equal(current.field(x), biot_savart(x, knot))  # from the kept table
    assert torch.equal(current.double().field(x.double()), biot_savart(x.double(), [lp.double() for lp in knot]))
    ring = [torch.tensor(circle(0.5, n=64), dtype=torch.float32)]
    other = neural_current(3, loops=ring, num_frequencies=4, width=8, depth=1)
    current.float().load_state_dict(other.state_dict())
    assert torch.equal(current.field(x), biot_savart(x, ring))
