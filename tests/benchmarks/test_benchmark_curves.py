"""The benchmark's curves with exact minimal areas (benchmarks/time_to_quality.py), against independent truth."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from conftest import load_benchmark
from scipy.integrate import quad

from deepcurrents.eval.metrics import mass_to_area
from deepcurrents.experiments.runner import build
from deepcurrents.geometry import biot_savart, load_boundary
from deepcurrents.models.current_module import input_frame


@pytest.mark.parametrize("name, radius, h",
                         [("catenoid", 0.5, 0.2), ("catenoid045", 0.45, 0.2), ("catenoid06", 0.6, 0.25)])
def test_catenoid_area_is_the_surface_of_revolution_integral(tmp_path, name, radius, h):
    ttq = load_benchmark("time_to_quality")
    c = ttq.catenoid_neck(radius, h)
    assert abs(c * math.cosh(h / c) - radius) < 1e-12
    assert c > h / 1.19967864  # the stable (outer) catenoid, not the inner one
    # area = ∫ 2π r √(1 + r'²) dz for r = c cosh(z/c), by quadrature
    area, _ = quad(lambda z: 2 * math.pi * c * math.cosh(z / c) * math.sqrt(1 + math.sinh(z / c) ** 2), -h, h)
    path, exact = ttq.curves(tmp_path)[name]
    assert abs(exact - area) < 1e-9
    assert exact < 2 * math.pi * radius**2  # below the two disks: the catenoid is the minimum
    top, bottom = load_boundary(path, normalize=False).loops
    vector_area = [0.5 * np.cross(lp, np.roll(lp, -1, 0)).sum(0) for lp in (top, bottom)]
    assert vector_area[0][2] > 0 > vector_area[1][2]  # opposite orientations: ∂ of the catenoid
    assert np.allclose(top[:, 2], h) and np.allclose(bottom[:, 2], -h)
    assert np.allclose(np.linalg.norm(top[:, :2], axis=1), radius)


@pytest.mark.parametrize("name, r", [("enneper05", 0.5), ("enneper06", 0.6), ("enneper07", 0.7)])
def test_enneper_area_is_the_integral_of_its_metric_and_the_curve_its_border(tmp_path, name, r):
    """Enneper's immersion X(u, v) = (u − u³/3 + uv², −v + v³/3 − u²v, u² − v²) has E = G = (1 + u² + v²)², F = 0:
    the area over the disk of radius r, by quadrature, and its border X(r cos t, r sin t), as the benchmark writes."""
    ttq = load_benchmark("time_to_quality")
    area, _ = quad(lambda rho: 2 * math.pi * rho * (1 + rho**2) ** 2, 0.0, r)
    path, exact = ttq.curves(tmp_path)[name]
    assert abs(exact - area) < 1e-12
    t = 2 * np.pi * np.arange(200) / 200
    u, v = r * np.cos(t), r * np.sin(t)
    border = np.stack([u - u**3 / 3 + u * v**2, -v + v**3 / 3 - u**2 * v, u**2 - v**2], -1)
    (loop,) = load_boundary(path, normalize=False).loops
    assert np.allclose(loop, border, atol=1e-8)


def _plane_normal(about_x: float, about_y: float) -> np.ndarray:
    """e_z turned as ``tilted`` turns it, written out by hand: R_y(b) R_x(a) e_z."""
    a, b = math.radians(about_x), math.radians(about_y)
    return np.array([math.cos(a) * math.sin(b), -math.sin(a), math.cos(a) * math.cos(b)])


@pytest.mark.parametrize("name, about_x, about_y, offset, area", [
    # the star's fan of triangles from its centre: ½ Σ r_i r_i+1 sin(2π/M)
    ("star", 30, 0, (0.1, 0.0, 0.05),
     0.5 * math.sin(2 * math.pi / 300) * float(np.sum((r := 0.45 + 0.15 * np.cos(10 * math.pi * np.arange(300) / 300))
                                                       * np.roll(r, -1)))),
    ("square12", 0, 20, (0.0, 0.0, 0.0), 1.2**2),
    ("small_circle", 50, 25, (0.3, -0.2, 0.1), 0.5 * 300 * 0.25**2 * math.sin(2 * math.pi / 300)),  # regular 300-gon
])
def test_planar_curves_lie_in_their_plane_and_bound_their_area(tmp_path, name, about_x, about_y, offset, area):
    ttq = load_benchmark("time_to_quality")
    path, exact = ttq.curves(tmp_path)[name]
    assert abs(exact - area) < 1e-12
    (loop,) = load_boundary(path, normalize=False).loops
    normal = _plane_normal(about_x, about_y)
    assert np.abs((loop - np.asarray(offset)) @ normal).max() < 1e-12  # planar: the flat region is the minimum
    # counter-clockwise about the normal (the vector area points along it)
    assert 0.5 * np.cross(loop, np.roll(loop, -1, 0)).sum(0) @ normal > 0


def test_star_is_close_to_its_smooth_curve():
    """The 300-vertex star's area is within O(1/M²) of the smooth r(t) = 0.45 + 0.15 cos 5t's ½∫r² dt."""
    ttq = load_benchmark("time_to_quality")
    smooth = math.pi * (0.45**2 + 0.15**2 / 2)
    assert 0 < smooth - ttq.polygon_area(ttq.tilted(ttq.star_points(), 30, 0)) < 1e-3


def test_score_gives_areas_in_the_curve_own_units_for_a_normalised_curve(tmp_path):
    """The star reaches 0.7 and is trained scaled into the safe box (data.normalize=auto): the benchmark's copy
    scores must be areas in the star's own units, like metrics.json's. Untrained (zero output layer), ω = s·α of the
    scaled curve; the same uniform samples mapped back to the star's frame and α of the star itself, computed there,
    give ∫_{U'} |s·α| = scale² ∫_U |s·α_model| independently of how the benchmark converts."""
    ttq = load_benchmark("time_to_quality")
    path, exact = ttq.curves(tmp_path)["star"]
    cfg = ttq.compose_cfg(["experiment=minimal_curve", f"data.curve={path}", "preset=cpu"])
    _, module = build(cfg)
    scale, offset = input_frame(module.hparams.boundary)
    assert scale > 1.05  # normalised
    n = 1 << 12
    (row,) = ttq.score(module, cfg, [{"state": module.current.state_dict(), "seconds": 0.0}], exact, n, mesh=False,
                       mesh_resolution=32)
    x = torch.rand(4 * n, 3, generator=torch.Generator().manual_seed(12345)) * 2.0 - 1.0  # score's samples
    star = torch.as_tensor(np.loadtxt(path))
    y = x.double() * scale + torch.as_tensor(offset)  # the same points in the star's frame
    alpha_scale = module.current.alpha_scale
    mean = float((alpha_scale * biot_savart(y, [star])).norm(dim=-1).mean())
    # over U' = scale·U + offset, whose volume is scale³ that of U
    expected = mass_to_area(mean, 3, alpha_scale) * scale**3
    assert row["mass_area"] == pytest.approx(expected, rel=1e-3)
    assert row["ratio"] == pytest.approx(expected / exact, rel=1e-3)


def test_helicoid_area_is_the_integral_of_its_metric_and_the_piece_a_graph_over_a_convex_domain(tmp_path):
    """The helicoid X(u, v) = (u cos v, u sin v, c v) has |X_u × X_v| = √(u² + c²): the area of |u| ≤ a,
    0 ≤ v ≤ θ by quadrature. Its unit normal (c sin v, −c cos v, u)/√(u² + c²) has a positive component along
    e = (sin θ/2, −cos θ/2, 0) on the whole closed piece (θ < π), so the piece is a graph over the plane ⊥ e, whose
    domain (|s| ≤ a cos(v − θ/2) at height c v) is convex: the unique minimiser. The written border runs along
    the piece's four sides."""
    ttq = load_benchmark("time_to_quality")
    a, c, turn = 0.6, 0.3, math.pi / 2
    path, exact = ttq.curves(tmp_path)["helicoid"]
    area, _ = quad(lambda u: turn * math.sqrt(u * u + c * c), -a, a)
    assert abs(exact - area) < 1e-12
    u, v = np.meshgrid(np.linspace(-a, a, 101), np.linspace(0.0, turn, 101))
    normal = np.stack([c * np.sin(v), -c * np.cos(v), u], -1) / np.sqrt(u**2 + c**2)[..., None]
    e = np.array([math.sin(turn / 2), -math.cos(turn / 2), 0.0])
    assert (normal @ e).min() > 0.1
    (loop,) = load_boundary(path, normalize=False).loops
    z = loop[:, 2] + c * turn / 2
    vertex_v = z / c  # the height gives v on every side
    assert vertex_v.min() > -1e-12 and vertex_v.max() < turn + 1e-12
    radial = loop[:, 0] * np.cos(vertex_v) + loop[:, 1] * np.sin(vertex_v)  # u
    across = -loop[:, 0] * np.sin(vertex_v) + loop[:, 1] * np.cos(vertex_v)
    assert np.abs(across).max() < 1e-12 and np.abs(radial).max() < a + 1e-12  # on the helicoid, |u| ≤ a
    on_side = (np.abs(np.abs(radial) - a) < 1e-12) | (np.abs(vertex_v) < 1e-12) | (np.abs(vertex_v - turn) < 1e-12)
    assert on_side.all()  # each vertex on a helical side or on a segment
    steps = np.linalg.norm(np.roll(loop, -1, 0) - loop, axis=1)
    assert steps.max() < 0.011  # the sides are sampled densely (no chord across the piece)


def test_tilted_catenoid_is_the_catenoid_turned_and_moved(tmp_path):
    """A rigid motion keeps the minimal area: the tilted pair's exact area is the axis-aligned pair's, and its loops
    are those loops turned by R_y(25°) R_x(40°) (written out by hand) and moved."""
    ttq = load_benchmark("time_to_quality")
    known = ttq.curves(tmp_path)
    path, exact = known["tilted_catenoid"]
    aligned_path, aligned_exact = known["catenoid045"]
    assert exact == aligned_exact
    a, b = math.radians(40), math.radians(25)
    rx = np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])
    ry = np.array([[math.cos(b), 0, math.sin(b)], [0, 1, 0], [-math.sin(b), 0, math.cos(b)]])
    for loop, aligned in zip(load_boundary(path, normalize=False).loops,
                             load_boundary(aligned_path, normalize=False).loops, strict=True):
        assert np.allclose(loop, aligned @ (ry @ rx).T + np.array([0.1, -0.05, 0.08]), atol=1e-9)


def test_a_curve_of_your_own_with_its_exact_area_runs_through_the_benchmark(tmp_path, monkeypatch, capsys):
    """time_to_quality.py --curves PATH=AREA: a reviewer's own curve (not in the repository) scored against the area
    they give, files written where --out says (a folder made first); impossible options and unknown curves are one
    sentence before anything trains."""
    import csv
    import json

    ttq = load_benchmark("time_to_quality")
    t = 2 * np.pi * np.arange(120) / 120
    ring = np.stack([0.3 * np.cos(t), 0.3 * np.sin(t), 0 * t], -1) + [0.1, 0.0, 0.05]
    odd = tmp_path / "a=b,c d"  # characters a Hydra override would split on: the value is quoted
    odd.mkdir()
    np.savetxt(odd / "ring.txt", ring)
    np.savetxt(tmp_path / "ring.txt", ring)
    np.savetxt(tmp_path / "circle05.txt", ring)
    exact = ttq.polygon_area(ring)
    out = tmp_path / "new" / "mine"
    monkeypatch.setattr("sys.argv", ["time_to_quality.py", "--steps", "3", "--copies", "1", "--mass-samples", "4096",
                                     "--recipes", "cpu", "--curves", f"{odd / 'ring.txt'}={exact}",
                                     "--out", str(out), "--threads", "1"])
    ttq.main()
    rows = list(csv.DictReader(open(tmp_path / "new" / "mine.csv")))
    assert [r["curve"] for r in rows] == ["ring"] and float(rows[0]["exact"]) == pytest.approx(exact)
    assert float(rows[0]["ratio"]) == pytest.approx(float(rows[0]["mass_area"]) / exact)
    assert (tmp_path / "new" / "mine.png").is_file() and json.loads((tmp_path / "new" / "mine.json").read_text())
    for argv, sentence in [
        (["--curves", "nowhere.txt=0.3"], "does not exist"),
        (["--curves", f"{tmp_path / 'ring.txt'}"], "unknown curve"),
        (["--curves", f"{tmp_path / 'ring.txt'}=big"], "PATH=AREA"),
        (["--steps", "0"], "--steps 0 must be greater than 0"),
        (["--seconds", "-3"], "--seconds -3.0 must be greater than 0"),
        (["--mass-samples", "0"], "--mass-samples 0 must be greater than 0"),
        (["--copies", "0"], "--copies 0 must be greater than 0"),
        (["--curves", f"{tmp_path / 'circle05.txt'}=0.3"], "is taken by a built-in curve"),
        (["--curves", f"{odd / 'ring.txt'}=0.3", f"{tmp_path / 'ring.txt'}=0.3"], "is taken by"),
        (["--out", ""], "must name the files' stem"),
        (["--out", "."], "must name the files' stem"),
    ]:
        monkeypatch.setattr("sys.argv", ["time_to_quality.py", *argv])
        with pytest.raises(SystemExit) as info:
            ttq.main()
        said = str(info.value.code) + capsys.readouterr().err
        assert sentence in said and "Traceback" not in said, (argv, said)


def test_help_lists_the_builtin_curves_and_their_names_match_curves(tmp_path, monkeypatch, capsys):
    """CURVE_NAMES (what --help lists without writing the curve files) is curves()'s names, in its order."""
    ttq = load_benchmark("time_to_quality")
    assert tuple(ttq.curves(tmp_path)) == ttq.CURVE_NAMES
    monkeypatch.setattr("sys.argv", ["time_to_quality.py", "--help"])
    with pytest.raises(SystemExit) as info:
        ttq.main()
    assert info.value.code == 0
    shown = " ".join(capsys.readouterr().out.split())  # argparse wraps the list
    assert all(name in shown for name in ttq.CURVE_NAMES)


def test_bad_curve_files_and_recipes_are_one_sentence_before_anything_trains(tmp_path, monkeypatch, capsys):
    """A curve file the loader refuses (2D points, NaN) and a recipe whose overrides do not compose or hold an
    impossible value end the script with one sentence and status 2 before the first run trains (train_recipe is
    replaced by a failure here), even when a good curve or recipe comes first."""
    ttq = load_benchmark("time_to_quality")

    def trained(*args, **kwargs):
        raise AssertionError("a run trained before the arguments were checked")

    monkeypatch.setattr(ttq, "train_recipe", trained)
    t = 2 * np.pi * np.arange(40) / 40
    np.savetxt(tmp_path / "flat.txt", np.stack([0.3 * np.cos(t), 0.3 * np.sin(t)], -1))
    ring = np.stack([0.3 * np.cos(t), 0.3 * np.sin(t), 0 * t], -1)
    ring[5, 1] = np.nan
    np.savetxt(tmp_path / "holed.txt", ring)
    common = ["--steps", "3", "--copies", "1", "--out", str(tmp_path / "out" / "x")]
    for argv, sentence in [
        (["--recipes", "cpu", "--curves", f"{tmp_path / 'flat.txt'}=0.28"], "must have 3 coordinates per vertex"),
        (["--recipes", "cpu", "--curves", "circle05", f"{tmp_path / 'holed.txt'}=0.28"], "NaN or infinite"),
        (["--recipes", "cpu", "--curves", "circle05", "--recipe", "noequals"], "must be NAME=OVERRIDE,OVERRIDE"),
        (["--recipes", "cpu", "--curves", "circle05", "--recipe", "x="], "must be NAME=OVERRIDE,OVERRIDE"),
        (["--recipes", "cpu", "x", "--curves", "circle05", "--recipe", "x=model.optim.lr=-1"],
         "recipe 'x' (model.optim.lr=-1) on curve 'circle05': model.optim.lr=-1 must be positive."),
        (["--recipes", "y", "--curves", "circle05", "--recipe", "y=notakey=3"], "Could not override 'notakey'"),
        (["--recipes", "y", "--curves", "circle05", "--recipe", "y=recipe=nope"], "Could not find 'recipe/nope'"),
        (["--recipes", "y", "--curves", "circle05", "--recipe", "y=preset=cpu,trainer.log_every_n_steps=0",
          "--step-cost"], "trainer.log_every_n_steps=0"),
    ]:
        monkeypatch.setattr("sys.argv", ["time_to_quality.py", *common, *argv])
        with pytest.raises(SystemExit) as info:
            ttq.main()
        err = capsys.readouterr().err
        assert info.value.code == 2 and sentence in err.splitlines()[-1] and "Traceback" not in err, (argv, err)
    assert not (tmp_path / "out" / "x.csv").exists()


def test_step_cost_writes_its_numbers_beside_the_other_modes(tmp_path, monkeypatch, capsys):
    """--step-cost writes <stem>_step_cost.json as --eval-cost writes <stem>_eval_cost.json (the measurement is
    replaced by fixed numbers here: nothing trains)."""
    import json

    ttq = load_benchmark("time_to_quality")
    seen = {}

    def fixed(recipes, curve):
        seen.update(recipes=list(recipes), curve=curve)
        return {"cpu": 0.02, "fast": 0.01}

    monkeypatch.setattr(ttq, "step_costs", fixed)
    monkeypatch.setattr("sys.argv", ["time_to_quality.py", "--step-cost", "--recipes", "cpu", "fast", "--curves",
                                     "circle05", "--out", str(tmp_path / "sc")])
    ttq.main()
    out = json.loads((tmp_path / "sc_step_cost.json").read_text())
    assert seen["recipes"] == ["cpu", "fast"] and seen["curve"].endswith("circle05.txt'")
    assert out["curve"] == "circle05" and out["seconds_per_step"] == {"cpu": 0.02, "fast": 0.01}
    assert out["ratio_to_first"] == {"cpu": 1.0, "fast": 0.5}
    assert "sc_step_cost.json" in capsys.readouterr().out
