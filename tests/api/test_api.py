"""The Python API (deepcurrents.minimal_surface / reconstruct / train / load and their results): the same run as
the command line's, fields and meshes in the input's coordinates, checkpoints read safely, one-sentence errors
before anything trains, families, the grid method's current."""

from __future__ import annotations

import csv
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh
from conftest import (
    QUIET_CPU,
    ROOT,
    TINY_EVAL,
    TINY_NET,
    Payload,
    run_command_in_process,
    spherical_cap,
    tiny_overrides,
    write_family,
)

import deepcurrents as dc
from deepcurrents.eval.metrics import boundary_error

pytestmark = pytest.mark.usefixtures("one_thread")

# the quiet tiny run of the tests, less the preset and the steps the API's keywords set
TINY = [o for o in QUIET_CPU if not o.startswith("preset=")] + TINY_NET + TINY_EVAL
STEPS = 40


def wavy_ring(n: int = 80, scale: float = 10.0, offset=(100.0, -50.0, 3.0)) -> np.ndarray:
    """A closed non-planar loop far outside the box (so the run moves it in: data.normalize=auto). → (n, 3)."""
    t = np.linspace(0.0, 2 * np.pi, n, endpoint=False)
    loop = np.stack([0.5 * np.cos(t), 0.5 * np.sin(t), 0.12 * np.cos(2 * t)], 1)
    return loop * scale + np.asarray(offset)


@pytest.fixture(scope="module")
def api_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("api") / "run"
    return dc.minimal_surface(wavy_ring(), steps=STEPS, overrides=TINY, out_dir=out)


def comparable(metrics: dict) -> dict:
    """Metrics less the clocks (``*_seconds``, throughput), which no two runs share."""
    return {k: v for k, v in metrics.items() if "seconds" not in k and "per_second" not in k}


def test_the_api_run_is_the_command_lines(api_run, tmp_path):
    curve = api_run.run_dir / "curve.obj"
    assert curve.is_file()  # the array became the run's own input file
    cli_dir = tmp_path / "cli"
    done = run_command_in_process("deepcurrents.cli.train", [
        "experiment=minimal_curve", f"data.curve={curve.resolve()}", "preset=cpu", f"trainer.max_steps={STEPS}",
        *TINY, f"hydra.run.dir={cli_dir}"], cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    cli = json.loads((cli_dir / "metrics.json").read_text())
    assert comparable(cli) == comparable(api_run.metrics)
    assert api_run.metrics["normalization_scale"] > 1  # the far, large ring was moved into the box
    # the recorded overrides repeat the run: the command line's record of the same command
    recorded = (api_run.run_dir / ".hydra" / "overrides.yaml").read_text()
    assert "experiment=minimal_curve" in recorded and "preset=cpu" in recorded


def test_fields_meshes_and_numbers_are_in_the_inputs_units(api_run):
    ring = wavy_ring()
    scale = api_run.scale
    offset = np.asarray(api_run.metrics["normalization_offset"])
    assert scale == pytest.approx(api_run.metrics["normalization_scale"])
    # Γ as given (to float64 rounding of the move into the box and back)
    np.testing.assert_allclose(api_run.boundary[0], ring, atol=1e-9)
    # f and ω at input points are the model's at the moved points; ω in input units is a 1-form: ω_model / scale
    x = ring[::7] + np.array([0.3, -0.2, 0.4])
    with torch.no_grad():
        f_model, w_model = api_run.current.evaluate(torch.as_tensor((x - offset) / scale, dtype=torch.float32))
    np.testing.assert_allclose(api_run.f(x), f_model.double().numpy(), rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(api_run.omega(x) * scale, w_model.double().numpy(), rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(api_run.f((x - offset) / scale, units="model"), api_run.f(x), rtol=1e-6, atol=1e-7)
    # ∇f by central differences in input units: (ω − α) scaled alike, so f's own slope is the model's / scale
    h = 1e-3 * scale
    e = np.eye(3)[0] * h
    slope = (api_run.f(x + e) - api_run.f(x - e)) / (2 * h)
    xm = torch.tensor((x - offset) / scale, dtype=torch.float32, requires_grad=True)
    grad = torch.autograd.grad(api_run.current.f(xm).sum(), xm)[0][:, 0].double().numpy() / scale
    np.testing.assert_allclose(slope, grad, rtol=2e-2, atol=2e-4)
    # the mesh is the run's mesh.ply, its border on the given curve
    mesh = api_run.mesh()
    saved = trimesh.load(api_run.run_dir / "mesh.ply", process=False)
    np.testing.assert_allclose(mesh.vertices, saved.vertices, atol=1e-9)
    assert mesh.area == pytest.approx(api_run.metrics["mesh_area"], rel=1e-9)
    assert boundary_error(mesh, [ring]) < 1e-6 * scale
    # the mass bound is the run's, in the curve's units (area ∝ scale²)
    assert api_run.mass_bound() == pytest.approx(api_run.metrics["mass_area"], rel=1e-9)
    assert api_run.mass_bound(units="model") == pytest.approx(api_run.metrics["mass_area"] / scale**2, rel=1e-9)


def test_the_polished_mesh_is_the_runs_in_the_inputs_units(api_run):
    metrics = api_run.metrics
    polished = api_run.polished()
    assert polished.stopped is None and metrics["polish_stopped"] is None
    assert polished.extrapolated == pytest.approx(metrics["mesh_area_extrapolated"], rel=1e-9)
    assert polished.curve_extrapolated == pytest.approx(metrics["mesh_area_smooth_curve"], rel=1e-9)
    assert polished.topology.describe() == metrics["surface"]
    saved = trimesh.load(api_run.run_dir / "mesh_polished.ply", process=False)
    np.testing.assert_allclose(polished.mesh.vertices, saved.vertices, atol=1e-9)
    assert boundary_error(polished.mesh, [wavy_ring()]) < 1e-6 * api_run.scale
    # the flow lowers the area below the extracted mesh's (the same units: the curve's)
    assert polished.area < metrics["mesh_area"] and polished.area == pytest.approx(metrics["mesh_area_polished"])
    assert len(api_run.polished(levels=3).areas) == 3
    with pytest.raises(dc.UserInputError, match="polished\\(\\) got level: its settings are"):
        api_run.polished(level=2)


def test_render_and_save(api_run, tmp_path):
    image = api_run.render(size=32, samples=8)
    assert image.shape == (32, 32, 3) and image.dtype == np.uint8 and image.min() < 250  # something drawn
    picture = api_run.render(size=120, mesh=True)
    assert picture.ndim == 3 and picture.shape[2] == 3
    copy = api_run.save(tmp_path / "kept" / "surface.ckpt")
    again = dc.load(copy)
    x = wavy_ring()[::5] * 1.01
    np.testing.assert_array_equal(again.f(x), api_run.f(x))
    assert again.metrics == {}  # a lone checkpoint file: no run folder beside it
    assert dc.load(api_run.run_dir).metrics == api_run.metrics  # a run's folder: its metrics too
    mesh_file = api_run.save(tmp_path / "surface.ply")
    np.testing.assert_allclose(trimesh.load(mesh_file, process=False).vertices, api_run.mesh().vertices, atol=1e-9)
    with pytest.raises(dc.UserInputError, match="suffix"):
        api_run.save(tmp_path / "surface.txt")


def test_a_crafted_checkpoint_is_refused_unrun(api_run, tmp_path):
    marker = tmp_path / "ran"
    ckpt = torch.load(api_run.checkpoint, weights_only=False)
    ckpt["hyper_parameters"]["note"] = Payload(f"touch {marker}")
    crafted = tmp_path / "colleague.ckpt"
    torch.save(ckpt, crafted)
    with pytest.raises(dc.CheckpointError, match="refused") as err:
        dc.load(crafted)
    assert isinstance(err.value, dc.UserInputError) and "\n" not in str(err.value)
    assert not marker.exists()
    (tmp_path / "empty").mkdir()
    with pytest.raises(dc.CheckpointError, match="without checkpoints/last.ckpt"):
        dc.load(tmp_path / "empty")
    with pytest.raises(dc.CheckpointError, match="does not exist"):
        dc.load(tmp_path / "missing.ckpt")


loop = wavy_ring(scale=1.0, offset=(0, 0, 0))


@pytest.mark.parametrize("call, words", [
    (lambda: dc.minimal_surface(loop[:, :2]), r"shape \(80, 2\)"),
    (lambda: dc.minimal_surface(np.where(np.arange(80)[:, None] == 3, np.nan, loop)), "NaN"),
    (lambda: dc.minimal_surface(loop[:2]), "at least 3"),
    (lambda: dc.minimal_surface([loop, loop[:, :1]]), r"curve\[1\] has shape"),
    (lambda: dc.minimal_surface("spiral"), "neither a known curve"),
    (lambda: dc.minimal_surface(loop, preset="huge"), "preset/huge.*available: cpu"),
    (lambda: dc.minimal_surface(loop, recipe="magic"), "recipe/magic"),
    (lambda: dc.minimal_surface(loop, steps=0), "steps=0 must be a positive integer"),
    (lambda: dc.minimal_surface(loop, max_time=-5), "max_time=-5 must be positive"),
    (lambda: dc.minimal_surface(loop, overrides="seed=1"), "must be a list of strings"),
    (lambda: dc.minimal_surface(loop, overrides=["model.net.widht=3"]), "model.net.widht"),
    (lambda: dc.reconstruct((loop, loop)), "needs boundary="),
    (lambda: dc.reconstruct((loop, loop[:5]), boundary=loop), "80 points but 5 normals"),
    (lambda: dc.reconstruct(trimesh.Trimesh(), ), "without faces"),
    (lambda: dc.reconstruct(spherical_cap(), boundary=loop), "its own border"),
    (lambda: dc.reconstruct(42), "give a mesh file"),
    (lambda: dc.train("fig5"), "experiment/fig5"),
])
def test_mistakes_are_one_sentence_before_anything_is_made(call, words, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(dc.UserInputError, match=words) as err:
        call()
    assert "\n" not in str(err.value).strip()
    assert not (tmp_path / "outputs").exists()  # refused before a run folder was made


def test_a_setting_refused_by_the_schema_is_one_sentence(tmp_path):
    with pytest.raises(dc.ConfigError, match="model.optim.lr"):
        dc.minimal_surface(loop, overrides=[*TINY, "model.optim.lr=-1"], out_dir=tmp_path / "run")
    assert not (tmp_path / "run").exists()  # refused before its folder was made


@pytest.mark.slow
def test_reconstruct_from_a_mesh_and_from_oriented_points(tmp_path):
    from deepcurrents.data.targets import mesh_boundary_loops, sample_mesh_surface

    cap = spherical_cap(subdivisions=2)
    settings = {"steps": 20, "overrides": TINY}
    from_mesh = dc.reconstruct(cap, out_dir=tmp_path / "mesh", **settings)
    written = trimesh.load(tmp_path / "mesh" / "target.ply", process=False)
    np.testing.assert_allclose(written.vertices, cap.vertices, atol=1e-12)
    assert from_mesh.metrics["ucd"] >= 0 and "ucd_reverse" in from_mesh.metrics
    pts, nrm = sample_mesh_surface(np.asarray(cap.vertices), np.asarray(cap.faces), 2000,
                                   torch.Generator().manual_seed(0))
    rim = mesh_boundary_loops(cap.vertices, cap.faces)[0]
    from_points = dc.reconstruct((pts, nrm), boundary=rim, out_dir=tmp_path / "points", **settings)
    assert np.load(tmp_path / "points" / "points.npy").shape == (2000, 6)
    assert (tmp_path / "points" / "boundary.obj").is_file()
    np.testing.assert_allclose(from_points.boundary[0], rim, atol=1e-9)  # Γ back in the cloud's coordinates
    assert "ucd" in from_points.metrics


@pytest.mark.slow
def test_a_family_answers_members_interpolants_and_new_boundaries(tmp_path_factory):
    data = write_family(tmp_path_factory.mktemp("discs"))
    out = tmp_path_factory.mktemp("family")
    keep = [o for o in tiny_overrides(data, out, 100) if not o.startswith(("experiment=", "preset=", "paths."))]
    family = dc.train("latent_hands", overrides=keep, out_dir=out)
    assert isinstance(family, dc.FamilyResult) and len(family) == 3 and family.shapes[0] == "000_cap.ply"
    x = np.random.default_rng(0).uniform(-0.6, 0.6, (50, 3))
    first, second = family.member(0), family.member(1)
    np.testing.assert_array_equal(family.interpolate(0, 1, 0.0).f(x), first.f(x))
    np.testing.assert_allclose(family.interpolate(0, 1, 1.0, mode="both").f(x), second.f(x), atol=1e-6)
    # a new boundary: shape 1's own loop, given reversed and with another start, is matched and turned back
    own = family.module.shape_loops(1)[0]
    np.testing.assert_allclose(family.generate([np.roll(own[::-1], 5, 0)], latent=1).boundary[0],
                               np.roll(own[::-1], 5, 0)[::-1], atol=1e-6)
    np.testing.assert_allclose(family.generate([own], latent=1).f(x), second.f(x), atol=1e-6)
    # a member's mesh is the one the run's own evaluation made of that shape (its per_shape.csv row)
    mesh = first.mesh()
    with open(out / "per_shape.csv") as fh:
        row = next(csv.DictReader(fh))
    assert row["name"] == "000_cap.ply" and len(mesh.faces) == int(row["mesh_faces"]) > 0
    assert mesh.area == pytest.approx(float(row["mesh_area"]), rel=1e-9)
    assert boundary_error(mesh, family.module.shape_loops(0)) == pytest.approx(float(row["boundary_error"]), rel=1e-9)
    assert first.mesh(resolution=24).vertices.shape != mesh.vertices.shape  # the resolution is honoured
    with pytest.raises(dc.ConfigError, match="i=7 is not a training shape"):
        family.member(7)
    with pytest.raises(dc.UserInputError, match="has no checkpoint of its own"):
        first.save(out / "member.ckpt")
    assert isinstance(dc.load(family.save(out / "family.ckpt")), dc.FamilyResult)


def test_the_grid_methods_current_loads_and_meshes(tmp_path):
    grid = dc.train("minimal_grid", steps=6, overrides=[*TINY, "data.curve=circle", "model.grid.resolution=10"],
                    out_dir=tmp_path / "grid")
    assert type(grid.module).__name__ == "GridModule"
    assert grid.f(np.zeros((1, 3))).shape == (1,) and grid.omega(np.zeros((2, 3))).shape == (2, 3)
    mesh = grid.mesh()
    assert mesh.area == pytest.approx(grid.metrics["mesh_area"], rel=1e-9)
    assert math.isfinite(grid.mass_bound(samples=4096))


def test_import_deepcurrents_is_light():
    code = "import sys, deepcurrents as dc; print('torch' in sys.modules, callable(dc.minimal_surface))"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT,
                          env={**os.environ, "PYTHONWARNINGS": "ignore"}, check=True)
    assert done.stdout.split() == ["False", "True"]  # the API is loaded on first use only


def test_a_path_is_quoted_for_hydra(tmp_path):
    odd = tmp_path / "a folder, with=odd 'chars'"
    odd.mkdir()
    ring = wavy_ring(scale=1.0, offset=(0, 0, 0))
    result = dc.minimal_surface(ring, steps=2, overrides=TINY, out_dir=odd / "run")
    assert result.run_dir == odd / "run" and (odd / "run" / "curve.obj").is_file()
    assert Path(json.loads(json.dumps(str(result.checkpoint)))).is_file()


def test_a_2d_current_answers_curves_and_its_picture(tmp_path):
    plane = dc.train("minimal_2d", steps=5, overrides=TINY, out_dir=tmp_path / "2d")
    assert plane.dim == 2 and plane.f(np.zeros((3, 2))).shape == (3,) and plane.omega(np.zeros((3, 2))).shape == (3, 2)
    assert all(c.ndim == 2 and c.shape[1] == 2 for c in plane.curves())
    assert plane.render().shape[2] == 3
    with pytest.raises(dc.UserInputError, match="use curves"):
        plane.mesh()
