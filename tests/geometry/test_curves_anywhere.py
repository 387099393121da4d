"""Curves anywhere, in any units (centred and scaled into the box, outputs back in the input's coordinates),
and dense or awkward curves (arc-length resampling with corners kept; self-intersecting and touching loops;
a loop through a sample point)."""

import json
import logging
import math
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh
from conftest import QUIET_CPU, TINY_NET, compose_cfg, validate_overrides
from omegaconf import OmegaConf

from deepcurrents.cli.extract import ExtractConfig, extract_checkpoint
from deepcurrents.data import MinimalSurfaceDataModule
from deepcurrents.errors import ConfigError, UserInputError
from deepcurrents.eval.metrics import boundary_error
from deepcurrents.experiments.runner import train
from deepcurrents.geometry import biot_savart, circle, solid_angle
from deepcurrents.geometry.curves import (
    SAFE_EXTENT,
    SMALL_EXTENT,
    box_normalisation,
    enneper,
    enneper_area,
    load_boundary,
    write_curve_file,
)
from deepcurrents.geometry.polyline import closed_loop_segments, polyline_hausdorff, resample_loop
from deepcurrents.losses import current_loss
from deepcurrents.nn import neural_current

# the disk test's small network (tests/models/test_minimal_training.py), quiet
SMALL = QUIET_CPU + [
    "callbacks.model_checkpoint.every_n_train_steps=100000", "data.num_samples=1024",
    "model.rff.num_frequencies=128", "model.net.width=64", "model.net.depth=3", "model.optim.lr=2e-3",
    "evaluation.mesh.resolution=64", "evaluation.mass_samples=262144",
]


def tilted_circle_mm(radius_mm: float = 40.0, n: int = 200) -> np.ndarray:
    """A circle of radius 40 (millimetres), tilted, far from the origin: nothing about it fits the box."""
    return circle(radius_mm, center=(120.0, -35.0, 250.0), normal=(1.0, 2.0, 2.0), n=n)


# ------------------------------------------------------------------------------------ normalisation


def mm_circle_file(folder: Path, radius_mm: float) -> tuple[np.ndarray, Path]:
    """``tilted_circle_mm(radius_mm)`` written as a one-loop .txt curve file in ``folder``. → (loop, path)."""
    loop = tilted_circle_mm(radius_mm)
    path = folder / "rim_mm.txt"
    np.savetxt(path, loop)
    return loop, path


def test_box_normalisation_auto_only_beyond_the_safe_extent():
    inside = np.array([[-0.3, 0.1, 0.0], [SAFE_EXTENT, -0.2, 0.1]])
    assert box_normalisation(inside, "auto", 0.5, SAFE_EXTENT) == (1.0, pytest.approx(np.zeros(3)))
    beyond = inside * 1.01
    scale, offset = box_normalisation(beyond, "auto", 0.5, SAFE_EXTENT)
    model = (beyond - offset) / scale
    # centred bounding box, largest extent fitted to [-0.5, 0.5]
    np.testing.assert_allclose(model.min(0) + model.max(0), 0.0, atol=1e-12)
    assert (model.max(0) - model.min(0)).max() == pytest.approx(1.0)
    assert box_normalisation(beyond, False, 0.5, SAFE_EXTENT)[0] == 1.0


def test_box_normalisation_auto_scales_up_small_curves(tmp_path, caplog):
    """A curve whose box's half-size is below SMALL_EXTENT is centred and scaled up to the normalised box (auto
    only, and only when a small extent is given); one at SMALL_EXTENT is left alone."""
    small = np.array([[0.3, 0.3, 0.0], [0.3 + 0.2, 0.3 - 0.1, 0.05]])  # half-size 0.1, off centre
    assert box_normalisation(small, "auto", 0.5, SAFE_EXTENT) == (1.0, pytest.approx(np.zeros(3)))
    scale, offset = box_normalisation(small, "auto", 0.5, SAFE_EXTENT, small_extent=SMALL_EXTENT)
    assert scale == pytest.approx(0.2)  # size 0.2 fitted to 1
    np.testing.assert_allclose(offset, [0.4, 0.25, 0.025], atol=1e-12)
    assert box_normalisation(small, False, 0.5, SAFE_EXTENT, small_extent=SMALL_EXTENT)[0] == 1.0
    edge = np.array([[-SMALL_EXTENT, 0.0, 0.0], [SMALL_EXTENT, 0.1, 0.0]])
    assert box_normalisation(edge, "auto", 0.5, SAFE_EXTENT, small_extent=SMALL_EXTENT)[0] == 1.0
    # through the data module: a circle of radius 0.2 becomes one of radius 0.5, its map back exact
    loop = circle(0.2, center=(0.1, 0.0, 0.0), n=64)
    path = tmp_path / "small.txt"
    np.savetxt(path, loop)
    with caplog.at_level(logging.INFO):
        boundary = MinimalSurfaceDataModule(curve=str(path)).boundary
    assert "is small" in caplog.text
    np.testing.assert_allclose(np.abs(boundary.loops[0]).max(0)[:2], [0.5, 0.5], atol=1e-3)
    np.testing.assert_allclose(boundary.to_input(boundary.loops[0]), loop, atol=1e-12)
    # the paper's named curves are not small: none of them moves
    for name in ("trefoil", "borromean", "circle"):
        assert not MinimalSurfaceDataModule(curve=name).boundary.normalized


def test_millimetre_curve_is_normalised_and_maps_back_exactly(tmp_path, caplog):
    loop = tilted_circle_mm()
    path = tmp_path / "rim_mm.txt"
    np.savetxt(path, loop)
    with caplog.at_level(logging.INFO):
        boundary = MinimalSurfaceDataModule(curve=str(path)).boundary
    assert "centred and scaled" in caplog.text
    model = boundary.loops[0]
    assert np.abs(model).max() <= 0.5 + 1e-12
    np.testing.assert_allclose(boundary.to_input(model), loop, atol=1e-9)
    # a similarity: the model curve is a circle of radius 40/scale
    assert np.linalg.norm(model - model.mean(0), axis=1) == pytest.approx(np.full(len(loop), 40.0 / boundary.scale))
    # normalize=false keeps the input and refuses it, naming the setting that helps
    with pytest.raises(UserInputError, match="outside the domain"):
        MinimalSurfaceDataModule(curve=str(path), normalize=False)


def test_paper_curves_are_not_moved_by_auto():
    for name in ("trefoil", "circle", "borromean"):
        boundary = MinimalSurfaceDataModule(curve=name).boundary
        assert not boundary.normalized, name


@pytest.mark.parametrize("value", [0, -1.0, float("nan"), float("inf")])
def test_curve_scale_must_be_positive(value):
    with pytest.raises(ConfigError, match=r"data\.curve_scale=.* must be a positive number"):
        validate_overrides(["experiment=minimal_trefoil", f"data.curve_scale={value}"])


@pytest.mark.parametrize("key,value", [("normalize", "sometimes"), ("max_vertices_per_loop", 2),
                                       ("max_vertices_per_loop", 2.5)])
def test_bad_curve_settings_are_one_sentence(key, value):
    with pytest.raises(ConfigError, match=rf"data\.{key}="):
        validate_overrides(["experiment=minimal_trefoil", f"data.{key}={value}"])


def test_curve_scale_zero_through_train_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError, match=r"data\.curve_scale=0"):
        train(compose_cfg(["experiment=minimal_trefoil", "data.curve_scale=0"] + SMALL), out_dir=tmp_path)


# ------------------------------------------------------------------------------------ resampling


def dense_square(per_side: int) -> np.ndarray:
    corners = np.array([[0.0, 0, 0], [0.5, 0, 0.1], [0.5, 0.5, 0], [0, 0.5, 0.1]]) - [0.25, 0.25, 0.05]
    return np.concatenate([a + np.linspace(0, 1, per_side, endpoint=False)[:, None] * (b - a)
                           for a, b in zip(corners, np.roll(corners, -1, 0), strict=True)]), corners


def test_resampling_keeps_corners_orientation_and_shape():
    loop, corners = dense_square(5000)
    out = resample_loop(loop, 64)
    assert out.shape == (64, 3)
    for c in corners:  # every corner is a vertex of the resampled loop
        assert np.linalg.norm(out - c, axis=1).min() < 1e-12
    np.testing.assert_allclose(out[0], loop[0])
    # same polygon: the corners are kept and the rest lies on the sides, so the shapes coincide
    s0, s1, _ = closed_loop_segments([loop])
    r0, r1, _ = closed_loop_segments([out])
    assert polyline_hausdorff(s0, s1, r0, r1, spacing=2e-3) < 2e-3
    # same orientation: the same solid angle (and α) seen from points off the curve
    probes = torch.tensor([[0.0, 0.0, 0.3], [0.1, -0.05, -0.2], [0.6, 0.2, 0.0]], dtype=torch.float64)
    a = solid_angle(probes, torch.as_tensor(loop))
    b = solid_angle(probes, torch.as_tensor(out))
    torch.testing.assert_close(torch.remainder(a - b + 2 * math.pi, 4 * math.pi) - 2 * math.pi,
                               torch.zeros(3, dtype=torch.float64), atol=1e-9, rtol=0)
    torch.testing.assert_close(biot_savart(probes, [torch.as_tensor(out)]),
                               biot_savart(probes, [torch.as_tensor(loop)]), rtol=1e-8, atol=1e-8)
    # a smooth loop: arc-length spacing, and its length kept to O(1/n²)
    smooth = circle(0.5, n=20_000)
    res = resample_loop(smooth, 256)
    gaps = np.linalg.norm(np.roll(res, -1, 0) - res, axis=1)
    assert gaps.max() / gaps.min() < 1.001
    assert abs(gaps.sum() - math.pi) < 2 * math.pi * (math.pi / 256) ** 2 / 6 * 1.1 + 1e-9


def test_dense_curve_file_is_resampled_with_a_warning(tmp_path, caplog):
    path = tmp_path / "rim.npy"
    np.save(path, circle(0.5, n=200_000))
    with caplog.at_level(logging.WARNING):
        boundary = MinimalSurfaceDataModule(curve=str(path)).boundary
    assert len(boundary.loops[0]) == 512
    assert "200000 vertices; resampled by arc length to 512" in caplog.text
    assert "data.max_vertices_per_loop" in caplog.text
    kept = MinimalSurfaceDataModule(curve=str(path), max_vertices_per_loop=None).boundary
    assert len(kept.loops[0]) == 200_000


# ------------------------------------------------------------------------------------ awkward curves


def figure_eight(n: int = 120) -> np.ndarray:
    """A self-intersecting planar loop (a lemniscate crossing itself at the origin), tilted out of plane."""
    t = 2 * np.pi * np.arange(n) / n
    return np.stack([0.5 * np.sin(t), 0.3 * np.sin(t) * np.cos(t), 0.1 * np.cos(t)], 1)


def touching_loops() -> list[np.ndarray]:
    """Two circles of radius 0.3 that touch at the origin (one shared point, not a shared vertex)."""
    return [circle(0.3, center=(-0.3, 0.0, 0.0), n=64), circle(0.3, center=(0.3, 0.0, 0.0), normal=(0, 1, 1), n=64)]


@pytest.mark.parametrize("kind", ["figure_eight", "touching", "through_sample"])
def test_awkward_curves_train_and_mesh(tmp_path, kind):
    # through_sample: a square whose vertices and sides lie on coordinates that samples and meshing grids hit
    square = np.array([[-0.5, -0.5, 0.0], [0.0, -0.5, 0.0], [0.5, -0.5, 0.0], [0.5, 0.5, 0.0], [-0.5, 0.5, 0.0]])
    loops = {"figure_eight": [figure_eight()], "touching": touching_loops(), "through_sample": [square]}[kind]
    path = tmp_path / f"{kind}.obj"
    write_curve_file(path, loops)
    # α is finite off Γ, including at the crossing's and the touching point's neighbours
    pts = torch.rand(4096, 3, generator=torch.Generator().manual_seed(0), dtype=torch.float64) * 2 - 1
    pts = torch.cat([pts, torch.tensor([[0.0, 0.0, 1e-3], [1e-3, 0.0, 0.0]], dtype=torch.float64)])
    alpha = biot_savart(pts, [torch.as_tensor(lp) for lp in loops])
    assert torch.isfinite(alpha).all()
    if kind == "through_sample":
        # samples exactly on a vertex and on a side of Γ: ω, the loss and its gradients stay finite
        on_curve = torch.tensor([[0.0, -0.5, 0.0], [-0.5, 0.0, 0.0], [0.25, -0.5, 0.0], [0.0, 0.0, 0.0]])
        current = neural_current(3, loops=[torch.as_tensor(square, dtype=torch.float32)], num_frequencies=16,
                                width=16, depth=2)
        batch = torch.cat([on_curve, torch.rand(60, 3) * 2 - 1])
        _, omega = current(batch, create_graph=True)
        loss = current_loss(omega)
        loss.backward()
        assert torch.isfinite(omega).all() and torch.isfinite(loss)
        assert all(torch.isfinite(q.grad).all() for q in current.parameters() if q.grad is not None)
    overrides = ["experiment=minimal_curve", f"data.curve={path}", "trainer.max_steps=30",
                 "evaluation.mesh.resolution=32", "evaluation.mass_samples=16384"]
    metrics = train(compose_cfg(overrides + QUIET_CPU + TINY_NET), out_dir=tmp_path / "run")
    assert math.isfinite(metrics["loss"]) and math.isfinite(metrics["mass_area"])
    mesh = trimesh.load(tmp_path / "run" / "mesh.ply", process=False)
    assert len(mesh.faces) > 0 and metrics["mesh_area"] > 0


# ------------------------------------------------------------------------------------ trained, in input units


@pytest.mark.slow
def test_millimetre_circle_gives_the_disk_in_millimetres(tmp_path):
    radius = 40.0
    loop, path = mm_circle_file(tmp_path, radius)
    # a planar circle's phase mesh is the disk after few steps: this checks units, not training
    overrides = ["experiment=minimal_curve", f"data.curve={path}", "trainer.max_steps=60",
                 "evaluation.mesh.resolution=48"]
    metrics = train(compose_cfg(overrides + SMALL), out_dir=tmp_path / "run")
    exact = math.pi * radius**2  # the 200-gon's area is 0.02% below
    scale = metrics["normalization_scale"]
    assert metrics["mesh_area"] == pytest.approx(exact, rel=0.02)
    assert metrics["mesh_area"] == pytest.approx(metrics["mesh_area_normalized"] * scale**2, rel=1e-12)
    assert metrics["mass_area"] > exact - 4 * metrics["mass_area_stderr"]  # still an upper bound, in mm²
    saved = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert saved["mesh_area"] == metrics["mesh_area"]
    # mesh.ply is in millimetres: its border lies on the input circle, its area is the reported one
    mesh = trimesh.load(tmp_path / "run" / "mesh.ply", process=False)
    assert mesh.area == pytest.approx(metrics["mesh_area"], rel=1e-6)
    err = boundary_error(mesh, [loop])
    # (the model's Γ is float32: 1e-7 of the curve's 250 mm offset)
    assert err == pytest.approx(metrics["boundary_error"], rel=1e-3, abs=1e-6 * 250)
    assert err < 0.02 * radius
    # the extract app writes the checkpoint's mesh in millimetres too
    cfg = OmegaConf.structured(ExtractConfig)
    for key, value in {"ckpt_path": str(tmp_path / "run" / "checkpoints" / "last.ckpt"), "out_dir": str(tmp_path / "x"),
                       "resolution": 48, "picture": False}.items():
        OmegaConf.update(cfg, key, value)
    summary = extract_checkpoint(cfg)
    assert summary["mesh_area"] == pytest.approx(metrics["mesh_area"], rel=1e-3)
    assert summary["mesh_area_normalized"] * summary["normalization_scale"] ** 2 == pytest.approx(summary["mesh_area"])
    extracted = trimesh.load(summary["mesh"], process=False)
    assert boundary_error(extracted, [loop]) < 0.02 * radius
    # render's mesh picture titles the area as the run's own mesh.png and metrics.json, in the curve's units (it
    # gave the box's 0.85 beside 3073 mm²); extract's title is its JSON's mesh_area
    from deepcurrents.models.current_module import reported_mesh_area
    from deepcurrents.models.loading import load_module

    module = load_module(tmp_path / "run" / "checkpoints" / "last.ckpt")
    assert reported_mesh_area(module, summary["mesh_area_normalized"]) == pytest.approx(summary["mesh_area"])


def test_a_curve_at_map_coordinates_gets_a_mesh_file_on_it(tmp_path):
    """A circle of radius 10 at UTM-sized coordinates (5.4e6): mesh.ply must lie on it as metrics.json says. A
    float32 PLY (trimesh's) rounded y to 0.5 units: its border 0.5 off the curve, its area 0.6 % too large."""
    t = 2 * np.pi * np.arange(64) / 64
    loop = np.stack([450000.0 + 10 * np.cos(t), 5400000.0 + 10 * np.sin(t), np.full_like(t, 100.0)], -1)
    path = tmp_path / "utm.txt"
    np.savetxt(path, loop, fmt="%.9f")
    overrides = ["experiment=minimal_curve", f"data.curve={path}", "trainer.max_steps=20",
                 "evaluation.mesh.resolution=32", "evaluation.sharpened.samples=0"]
    metrics = train(compose_cfg(overrides + SMALL), out_dir=tmp_path / "run")
    mesh = trimesh.load(tmp_path / "run" / "mesh.ply", process=False)
    assert b"property double x" in (tmp_path / "run" / "mesh.ply").read_bytes()[:400]
    assert mesh.area == pytest.approx(metrics["mesh_area"], rel=1e-9)
    # on Γ up to the model's float32 Γ in the box (6e-8 of its 0.5 half-width, times the scale of about 20)
    assert boundary_error(mesh, [loop]) < 1e-4
    assert metrics["mesh_area"] == pytest.approx(math.pi * 100, rel=0.02)  # the planar disk


@pytest.mark.slow
def test_enneper_at_097_gets_the_exact_area(tmp_path):
    """Enneper's curve of parameter radius 0.8 reaches 0.97 from the centre of the box: left there, the wall
    takes 13% off the converged grid current's area (benchmarks/curve_margin.py); normalised, a short CPU
    run meshes its minimal surface."""
    exact = enneper_area(0.8)
    assert float(np.linalg.norm(enneper(200)[0], axis=1).max()) == pytest.approx(0.9707, abs=1e-3)
    boundary = load_boundary("enneper", n=200, normalize="auto")
    assert boundary.normalized
    overrides = ["experiment=minimal_curve", "data.curve=enneper", "data.curve_vertices=200",
                 "trainer.max_steps=600", "model.optim.step_size=300"]
    metrics = train(compose_cfg(overrides + SMALL), out_dir=tmp_path)
    assert metrics["mesh_area"] == pytest.approx(exact, rel=0.03), metrics
    assert metrics["mass_area"] > exact - 4 * metrics["mass_area_stderr"], metrics
    mesh = trimesh.load(tmp_path / "mesh.ply", process=False)
    assert boundary_error(mesh, enneper(200)) < 0.03


@pytest.mark.slow
def test_grid_method_reports_a_millimetre_curve_in_millimetres(tmp_path):
    radius = 40.0
    loop, path = mm_circle_file(tmp_path, radius)
    overrides = ["experiment=minimal_grid", f"data.curve={path}", "model.grid.resolution=32",
                 "trainer.max_steps=150", "evaluation.mesh.resolution=48", "evaluation.mass_samples=16384"]
    metrics = train(compose_cfg(overrides + QUIET_CPU), out_dir=tmp_path / "run")
    exact = math.pi * radius**2
    scale = metrics["normalization_scale"]
    assert metrics["mesh_area"] == pytest.approx(exact, rel=0.05), metrics
    assert metrics["mass_area"] == pytest.approx(metrics["mass_area_normalized"] * scale**2, rel=1e-12)
    assert metrics["mass_area_lower"] < metrics["mass_area"]
    mesh = trimesh.load(tmp_path / "run" / "mesh.ply", process=False)
    assert mesh.area == pytest.approx(metrics["mesh_area"], rel=1e-6)
    assert boundary_error(mesh, [loop]) < 0.05 * radius


def test_biot_savart_and_solid_angle_stay_differentiable_in_points_and_loops():
    """The matrix form keeps the contract: first and second derivatives in the points and the loop's vertices
    match finite differences (float64)."""
    gen = torch.Generator().manual_seed(0)
    pts = (torch.rand(5, 3, generator=gen, dtype=torch.float64) * 2 - 1).requires_grad_()
    loop = (torch.as_tensor(circle(0.5, n=7)) + 0.05 * torch.randn(7, 3, generator=gen, dtype=torch.float64))
    loop.requires_grad_()
    assert torch.autograd.gradcheck(lambda p, v: biot_savart(p, [v]), (pts, loop))
    assert torch.autograd.gradgradcheck(lambda p, v: biot_savart(p, [v]), (pts, loop))
    assert torch.autograd.gradcheck(lambda p, v: solid_angle(p, [v]), (pts, loop))
