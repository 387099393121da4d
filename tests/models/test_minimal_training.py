"""Short CPU trainings against exact answers: the disk spanning a planar circle, the segment between two
points in 2D. The mass bound must never undercut the exact area/length and must decrease with training."""

import json
import math

import numpy as np
import pytest
import torch
from conftest import compose_cfg

from deepcurrents.experiments.runner import train

pytestmark = pytest.mark.slow  # minutes of CPU training against exact answers

SMALL = [
    "logger=csv", "preset=cpu", "trainer=cpu", "trainer.enable_progress_bar=false",
    "trainer.enable_model_summary=false", "trainer.log_every_n_steps=25", "evaluation.mass_samples=1048576",
    "callbacks.model_checkpoint.every_n_train_steps=100000",
]


def logged_mass(out_dir, key):
    import csv

    rows = list(csv.DictReader(open(next(out_dir.glob("csv/*/metrics.csv")))))
    return np.array([float(r[key]) for r in rows if r.get(key)])


def test_planar_circle_gives_the_disk(tmp_path):
    radius = 0.5
    exact = math.pi * radius**2
    overrides = ["experiment=minimal_trefoil", "data.curve=circle", f"data.curve_scale={radius / 0.6}",
                 "trainer.max_steps=700", "model.optim.step_size=350", "data.num_samples=1024",
                 "model.rff.num_frequencies=128", "model.net.width=64", "model.net.depth=3", "model.optim.lr=2e-3",
                 "evaluation.mesh.resolution=64"]
    metrics = train(compose_cfg(overrides + SMALL), out_dir=tmp_path)
    # mesh: within 10% of the disk, border on the circle (to the meshing tolerance)
    assert abs(metrics["mesh_area"] - exact) < 0.10 * exact, metrics
    assert metrics["boundary_error"] < 0.02, metrics
    # the mass bound is an upper bound (4 standard errors of Monte Carlo slack), decreasing with training
    assert metrics["mass_area"] > exact - 4 * metrics["mass_area_stderr"], metrics
    trace = logged_mass(tmp_path, "train/mass_area")
    assert trace[-5:].mean() < trace[:5].mean()
    saved = json.loads((tmp_path / "metrics.json").read_text())
    assert saved["steps"] == 700
    # the run meshed by the phase (auto for minimal surfaces); the paper's level set f = s gives the same disk,
    # and the phase mesh's vertices lie where e^{iφ} is opposite its off-surface value θ
    from deepcurrents.eval.meshing import current_phase, extract_surface
    from deepcurrents.eval.metrics import boundary_error
    from deepcurrents.models.loading import load_module

    current = load_module(tmp_path / "checkpoints" / "last.ckpt").current
    phase = extract_surface(current, resolution=64, method="phase")
    level = extract_surface(current, resolution=64, method="level_set")
    assert phase.mesh.area == pytest.approx(metrics["mesh_area"], rel=1e-9)
    # the level set after 700 small steps is not converged: its excess area depends on the sample stream
    # (measured +0.6% … +29% over six seeds and streams, the phase mesh within 0.2% in each), so what holds for
    # any seed is checked: it spans the circle (border on Γ), and no surface spanning it is smaller than the disk
    assert level.mesh.area > 0.98 * exact
    assert boundary_error(level.mesh, [c.cpu().double().numpy() for c in current.loops]) < 0.02
    inner = phase.mesh.vertices[np.linalg.norm(phase.mesh.vertices[:, :2], axis=1) < 0.8 * radius]
    rel = current_phase(current, torch.as_tensor(inner, dtype=torch.float32)).numpy() - phase.level
    assert np.abs(np.sin(rel)).max() < 0.1 and np.cos(rel).max() < 0


def test_two_points_give_the_segment(tmp_path):
    exact = 1.0  # points (±0.5, 0)
    overrides = ["experiment=minimal_2d", "trainer.max_steps=600", "model.optim.step_size=300",
                 "data.num_samples=1024", "model.rff.num_frequencies=64", "model.net.width=64",
                 "model.net.depth=3", "model.optim.lr=2e-3"]
    metrics = train(compose_cfg(overrides + SMALL), out_dir=tmp_path)
    assert abs(metrics["curve_length"] - exact) < 0.10 * exact, metrics
    assert metrics["mass_length"] > exact - 4 * metrics["mass_length_stderr"], metrics
    trace = logged_mass(tmp_path, "train/mass_length")
    assert trace[-5:].mean() < trace[:5].mean()


def test_phase_sharpening_lowers_the_circles_bound_and_keeps_it_a_bound(tmp_path):
    """model.net.phase_sharpening (nn.NeuralCurrent): the same short run on the circle with and without it; the
    sharpened current's mass bound is lower, still above the disk (4 standard errors), its mesh still the disk;
    the checkpoint keeps κ and the level c."""
    radius = 0.5
    exact = math.pi * radius**2
    overrides = ["experiment=minimal_trefoil", "data.curve=circle", f"data.curve_scale={radius / 0.6}",
                 "trainer.max_steps=400", "data.num_samples=1024", "model.rff.num_frequencies=64",
                 "model.net.width=32", "model.net.depth=2", "evaluation.mesh.resolution=48",
                 "evaluation.mass_samples=262144", "data.sampling.kind=importance"]
    plain = train(compose_cfg(overrides + SMALL), out_dir=tmp_path / "plain")
    sharpening = ["model.net.phase_sharpening=2", "model.net.phase_sharpening_start=0.5"]
    sharp = train(compose_cfg(overrides + SMALL + sharpening), out_dir=tmp_path / "sharp")
    assert sharp["mass_area"] < plain["mass_area"] - 2 * plain["mass_area_stderr"], (plain, sharp)
    assert sharp["mass_area"] > exact - 4 * sharp["mass_area_stderr"], sharp
    assert abs(sharp["mesh_area"] - exact) < 0.05 * exact and sharp["boundary_error"] < 0.02, sharp
    from deepcurrents.models.loading import load_module

    current = load_module(tmp_path / "sharp" / "checkpoints" / "last.ckpt").current
    assert float(current.sharpening) == 2.0 and math.isfinite(float(current.sharpening_level))
