"""Shapes held out of a family's training (data.held_out): the split, the autodecoder's test-time latent fit
(only z moves, the loss drops), the final evaluation's ucd_held_out_mean; and the optional interpolation
regulariser (model.interpolation_weight, interpolation_mix): its loss is the Euclidean mass of the blended
shape; and the training shapes' own Euclidean mass term (model.mass_weight)."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import SHAPES, compose_cfg, disc_mesh, tiny_overrides, validate_overrides, write_family

from deepcurrents.data.family import FamilyDataModule, collate_shapes, split_held_out
from deepcurrents.data.targets import MeshTarget, target_sample
from deepcurrents.errors import ConfigError
from deepcurrents.eval.metrics import point_mesh_distance
from deepcurrents.losses import current_loss
from deepcurrents.models.autodecoder import AutodecoderModule, CheckpointMismatchError

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def discs(tmp_path_factory) -> Path:
    """Four discs: the three of test_family and a fourth cap, lower, to hold out."""
    d = write_family(tmp_path_factory.mktemp("discs4"))
    disc_mesh(lambda x, y: 1.2 * (0.35**2 - x**2 - y**2), radius=0.25, center=(0.0, 0.0, -0.5)).export(
        d / "003_low_cap.ply")
    return d


def test_held_out_split_takes_the_last_files_and_max_meshes_of_the_others():
    files = [Path(f"{i:03d}.ply") for i in range(8)]
    train, held = split_held_out(files, 4, 2)
    assert [p.stem for p in train] == ["000", "001", "002", "003"] and [p.stem for p in held] == ["006", "007"]
    assert split_held_out(files, None, 0) == (files, [])
    with pytest.raises(ConfigError, match=r"data.held_out=8 leaves no mesh to train on: the family has 8"):
        split_held_out(files, None, 8)
    with pytest.raises(ConfigError, match=r"data.held_out=-1 must be zero or a positive integer"):
        split_held_out(files, None, -1)


def test_datamodule_keeps_held_out_meshes_out_of_the_model(discs):
    dm = FamilyDataModule(str(discs), held_out=1, meshes_per_batch=2, num_samples=16, num_surface_samples=8)
    assert [m.name for m in dm.meshes] == ["000_cap.ply", "001_saddle.ply", "002_wave.ply"]
    assert [m.name for m in dm.held_out_meshes] == ["003_low_cap.ply"]
    kwargs = dm.model_kwargs()
    assert kwargs["num_shapes"] == 3 and "003_low_cap.ply" not in kwargs["shape_names"]
    # the held-out loop is matched to the family's reference: same start vertex direction, same orientation
    ref, held = dm.meshes[0].loop_points()[0], dm.held_out_meshes[0].loop_points()[0]
    np.testing.assert_allclose((held - held.mean(0))[0], (ref - ref.mean(0))[0], atol=1e-9)


def small_module(num_shapes: int = 3) -> AutodecoderModule:
    """A small untrained autodecoder whose output layer is not zero (so f depends on z from the start)."""
    torch.manual_seed(0)
    loops = [[disc_mesh(h, radius=0.25).vertices[-24:]] for h in list(SHAPES.values())[:num_shapes]]
    return AutodecoderModule(
        num_shapes=num_shapes, num_loops=1, shape_names=[f"s{i}" for i in range(num_shapes)],
        net={"width": 32, "depth": 2, "activation": "softplus", "alpha_scale": 1e-3, "zero_init_output": False},
        rff={"num_frequencies": 16, "sigma": 2.0, "enabled": True, "seed": 0},
        optim={"lr": 1e-3, "step_size": 100, "gamma": 0.5}, latent_dim=8, boundary_dim=8, surface_weight=5.0,
        train_loops=loops, train_bounds=[np.array([[-0.3, -0.3, -0.2], [0.3, 0.3, 0.2]])] * num_shapes)


def fixed_batch(mesh, seed: int = 7) -> dict[str, torch.Tensor]:
    loops = [mesh.vertices[-24:]]
    target = MeshTarget(mesh.vertices, mesh.faces, loops)
    item = target_sample(target, 512, 256, torch.Generator().manual_seed(seed))
    item["index"], item["loops"] = 0, loops
    return collate_shapes([item])


def test_latent_fit_moves_only_z_and_lowers_the_loss():
    module = small_module()
    before = {k: v.clone() for k, v in module.state_dict().items()}
    flags = [p.requires_grad for p in module.parameters()]
    mesh = disc_mesh(lambda x, y: 1.0 * (x**2 - 0.5 * y**2), radius=0.25)  # not a training shape
    batch = fixed_batch(mesh)
    z0 = module.family.latents.weight.detach().mean(0, keepdim=True)
    loss0 = float(module.compute_losses(batch, z0)["loss"].detach())
    z, history = module.fit_latent(mesh.vertices, mesh.faces, [mesh.vertices[-24:]], steps=60, lr=0.1,
                                   num_samples=512, num_surface_samples=256, seed=1)
    assert z.shape == (8,) and len(history) == 60
    loss1 = float(module.compute_losses(batch, z[None])["loss"].detach())  # on a batch the fit never saw
    assert loss1 < 0.85 * loss0, (loss0, loss1)
    assert np.mean(history[-6:]) < np.mean(history[:6])
    for key, value in module.state_dict().items():  # decoder, encoders and training codes untouched
        assert torch.equal(value, before[key]), key
    assert [p.requires_grad for p in module.parameters()] == flags
    with pytest.raises(ConfigError, match="model.latent_fit.steps"):
        module.fit_latent(mesh.vertices, mesh.faces, [mesh.vertices[-24:]], steps=0)
    # the surface loss's ε (data.surface_epsilon, a distance or a range) reaches the fit's samples
    short = {"steps": 3, "lr": 0.1, "num_samples": 64, "num_surface_samples": 64, "seed": 1}
    paper = module.fit_latent(mesh.vertices, mesh.faces, [mesh.vertices[-24:]], **short)[1]
    ranged = module.fit_latent(mesh.vertices, mesh.faces, [mesh.vertices[-24:]], surface_epsilon=(0.02, 0.04),
                               **short)[1]
    assert np.all(np.isfinite(ranged)) and ranged != paper


def test_latent_fit_prior_holds_the_code_near_the_training_codes():
    """``prior_weight`` w adds w·|z − μ|²/s²: a strong prior keeps z near the training codes' mean μ where the
    plain fit moves away, and the recorded history is the training losses alone (equal at the first step, where
    z = μ and both fits draw the same samples)."""
    module = small_module()
    mesh = disc_mesh(lambda x, y: 1.0 * (x**2 - 0.5 * y**2), radius=0.25)  # not a training shape
    loops = [mesh.vertices[-24:]]
    codes = module.family.latents.weight.detach()
    mean = codes.mean(0)
    spread = float(((codes - mean) ** 2).sum(1).mean())
    kwargs = {"steps": 40, "lr": 0.05, "num_samples": 256, "num_surface_samples": 128, "seed": 3}
    free, free_history = module.fit_latent(mesh.vertices, mesh.faces, loops, **kwargs)
    held, held_history = module.fit_latent(mesh.vertices, mesh.faces, loops, prior_weight=1e3, **kwargs)
    assert float((free - mean).norm()) > 0.5 * spread**0.5  # the plain fit leaves the codes' mean
    assert float((held - mean).norm()) < 0.2 * float((free - mean).norm())
    # the first step of each fit sees the same samples at z = μ, where the prior's gradient is zero: same losses
    assert held_history[0] == pytest.approx(free_history[0], rel=1e-6)
    with pytest.raises(ConfigError, match="model.latent_fit.prior_weight=-1"):
        validate_overrides(["experiment=latent_hands", "model.latent_fit.prior_weight=-1.0"])


def test_interpolation_loss_is_the_euclidean_mass_of_the_blended_shape():
    """Two copies of one shape: every interpolant is that shape, so the term is E_x|ω(x)| (B = I) of its
    current at the same uniform points, computed here through the single-member view."""
    module = small_module()
    module.train()
    loops = torch.as_tensor(disc_mesh(SHAPES["000_cap"], radius=0.25).vertices[-24:], dtype=torch.float32)
    padded = loops[None, None].repeat(2, 1, 1, 1)
    mask = torch.ones(2, 1, 24, dtype=torch.bool)
    z = module.family.latents.weight[:1].detach().repeat(2, 1)
    torch.manual_seed(3)
    got = module.interpolation.loss(module.family, z, padded, mask, 300)
    torch.manual_seed(3)
    torch.rand(2, 1)  # the two t's
    x = torch.rand(2, 300, 3) * 2 - 1
    member = module.member(z[0], [loops.numpy()])
    want = current_loss(torch.cat([member(xs, create_graph=False)[1] for xs in x]))
    assert float(got.detach()) == pytest.approx(float(want), rel=1e-5)
    # gradients reach the decoder; shapes with other loop sizes are not blended
    got.backward()
    assert module.family.mlp.net[0].weight.grad.abs().sum() > 0
    short = mask.clone()
    short[1, 0, -1] = False
    assert module.interpolation.loss(module.family, z, padded, short, 10) is None
    with pytest.raises(ConfigError, match="interpolation_weight"):
        validate_overrides(["experiment=latent_hands", "model.interpolation_weight=-1.0"])


def test_independent_mix_blends_code_and_boundary_apart():
    """interpolation_mix=independent: the pair's code at t and its boundary at another s (the grid's
    off-diagonal members), checked against the member (z_t, Γ_s) built by hand."""
    module = small_module()
    module.interpolation.mix = "independent"
    module.train()
    rims = [torch.as_tensor(disc_mesh(SHAPES[k], radius=0.25).vertices[-24:], dtype=torch.float32)
            for k in ("000_cap", "001_saddle")]
    padded = torch.stack(rims)[:, None]  # (2, 1, 24, 3)
    mask = torch.ones(2, 1, 24, dtype=torch.bool)
    z = module.family.latents.weight[:2].detach()
    torch.manual_seed(5)
    got = module.interpolation.loss(module.family, z, padded, mask, 200)
    torch.manual_seed(5)
    t, s = torch.rand(2, 1), torch.rand(2, 1)
    x = torch.rand(2, 200, 3) * 2 - 1
    assert not torch.allclose(t, s)
    omegas = []
    for k, (i, j) in enumerate(((0, 1), (1, 0))):  # each shape with the next one, cyclically
        zk = (1 - t[k]) * z[i] + t[k] * z[j]
        loop = (1 - s[k]) * rims[i] + s[k] * rims[j]
        omegas.append(module.member(zk, [loop.numpy()])(x[k], create_graph=False)[1])
    assert float(got.detach()) == pytest.approx(float(current_loss(torch.cat(omegas))), rel=1e-5)
    with pytest.raises(ConfigError, match="model.interpolation_mix='diagonal'"):
        validate_overrides(["experiment=latent_hands", "model.interpolation_mix=diagonal"])


def test_near_interpolation_points_keep_the_uniform_mean_and_sit_on_both_shapes():
    """model.interpolation_sampling.kind=near: the regulariser's points concentrate around the surface samples
    of the pair's two shapes, and their importance weights keep E[w g(x)] = E_U[g] (checked for g = 1 and
    g = x₀², whose uniform means are 1 and 1/3, to a few standard errors of 4 × 20,000 points)."""
    module = small_module()
    module.interpolation.sampling = {"kind": "near", "near_sigma": 0.03, "uniform_fraction": 0.5, "weighted": True}
    torch.manual_seed(0)
    surface = torch.stack([torch.rand(64, 3) * 0.2 - 0.6, torch.rand(64, 3) * 0.2 + 0.4])  # two far-apart shapes
    i, j = torch.tensor([0, 1]), torch.tensor([1, 0])
    x, w = module.interpolation.points(i, j, 20000, surface, torch.float32)
    assert x.shape == (2, 20000, 3) and w.shape == (2, 20000)
    for g, exact in ((torch.ones_like(x[..., 0]), 1.0), (x[..., 0] ** 2, 1.0 / 3.0)):
        values = (w * g).double().flatten()
        assert float(values.mean()) == pytest.approx(exact, abs=4 * float(values.std()) / len(values) ** 0.5)
    near = [torch.cdist(x[0], surface[k]).min(1).values < 0.1 for k in (0, 1)]
    # half the points are near samples, split between the two shapes; uniform ones land there rarely
    assert 0.2 < float(near[0].float().mean()) < 0.3 and 0.2 < float(near[1].float().mean()) < 0.3
    # a uniform point far from both shapes weighs ≈ 1 / u = 2
    far = ~(near[0] | near[1])
    assert float(w[0][far].median()) == pytest.approx(2.0, rel=1e-3)
    # the loss through them: finite, and gradients reach the decoder
    loops = torch.as_tensor(disc_mesh(SHAPES["000_cap"], radius=0.25).vertices[-24:], dtype=torch.float32)
    module.train()
    loss = module.interpolation.loss(module.family, module.family.latents.weight[:2].detach(),
                                     loops[None, None].repeat(2, 1, 1, 1), torch.ones(2, 1, 24, dtype=torch.bool), 100,
                                     surface)
    loss.backward()
    assert torch.isfinite(loss) and module.family.mlp.net[0].weight.grad.abs().sum() > 0
    with pytest.raises(ConfigError, match=r"model.interpolation_sampling.near_sigma=0 must be positive"):
        AutodecoderModule(**{**module.hparams, "interpolation_sampling": {"kind": "near", "near_sigma": 0}})
    with pytest.raises(ConfigError, match=r"model.interpolation_sampling has unknown keys \['anchors'\]"):
        AutodecoderModule(**{**module.hparams, "interpolation_sampling": {"kind": "near", "anchors": 8}})


def test_mass_weight_adds_the_shapes_euclidean_mass():
    """model.mass_weight=λ: the loss grows by λ·mean_x |ω(x)| (B = I) at the batch's own samples, computed
    here through the single-member view; the current loss (metric B_x) is unchanged."""
    module = small_module()
    mesh = disc_mesh(SHAPES["000_cap"], radius=0.25)
    batch = fixed_batch(mesh)
    plain = module.compute_losses(batch)
    module.hparams.mass_weight = 0.05
    weighted = module.compute_losses(batch)
    omega = module.member(module.latent(0), [mesh.vertices[-24:]])(batch["x"][0], create_graph=False)[1]
    mass = float(omega.detach().norm(dim=-1).mean())
    assert float(weighted["mass_loss"].detach()) == pytest.approx(mass, rel=1e-5)
    assert float(weighted["current_loss"].detach()) == pytest.approx(float(plain["current_loss"].detach()), rel=1e-6)
    assert float((weighted["loss"] - plain["loss"]).detach()) == pytest.approx(0.05 * mass, rel=1e-4)
    assert "mass_loss" not in plain
    with pytest.raises(ConfigError, match="model.mass_weight=-1"):
        validate_overrides(["experiment=latent_hands", "model.mass_weight=-1.0"])


@pytest.mark.slow
def test_final_evaluation_reports_held_out_shapes(discs, tmp_path):
    from deepcurrents.experiments.runner import train

    steps = 60
    cfg = compose_cfg(tiny_overrides(discs, tmp_path, steps) + [
        "data.held_out=1", "model.latent_fit.steps=40", "model.latent_fit.num_samples=256",
        "model.latent_fit.num_surface_samples=192", "model.interpolation_weight=1.0",
        "model.interpolation_sampling.kind=near"])
    metrics = train(cfg, out_dir=tmp_path)
    saved = json.loads((tmp_path / "metrics.json").read_text())
    with open(tmp_path / "per_shape.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["split"] for r in rows] == ["train"] * 3 + ["held_out"]
    held = rows[-1]
    assert held["name"] == "003_low_cap.ply" and metrics["held_out_shapes"] == 1
    assert saved["ucd_held_out_mean"] == pytest.approx(float(held["ucd"]))
    assert saved["ucd"] == pytest.approx(np.mean([float(r["ucd"]) for r in rows[:3]]))
    # the reported UCD is the distance from the held-out target to the mesh written for it
    import trimesh

    mesh = trimesh.load(tmp_path / "meshes" / "held_out_000_003_low_cap.ply", process=False)
    target = trimesh.load(discs / "003_low_cap.ply", process=False)
    assert point_mesh_distance(target.sample(20000, seed=1), mesh).mean() == pytest.approx(float(held["ucd"]),
                                                                                          rel=0.1)


def test_a_checkpoint_of_a_family_with_several_loops_is_checked_against_its_own_family():
    """loop_lengths is (S, B): a two-loop family's own hyperparameters pass the check on loading (comparing its
    rows as arrays raised 'truth value ... ambiguous' for B ≥ 2, so no heads checkpoint opened in the apps), and
    one changed vertex count is refused in one sentence."""
    rng = np.random.default_rng(0)
    loops = [[rng.normal(size=(n, 3)) * 0.1 for n in (12 + i, 20)] for i in range(3)]
    module = AutodecoderModule(
        num_shapes=3, num_loops=2, shape_names=["a", "b", "c"],
        net={"width": 16, "depth": 2, "activation": "softplus", "alpha_scale": 1e-3},
        rff={"num_frequencies": 8, "sigma": 2.0, "enabled": True, "seed": 0},
        optim={"lr": 1e-3, "step_size": 100, "gamma": 0.5}, latent_dim=4, boundary_dim=4,
        train_loops=loops, train_bounds=[np.array([[-0.3] * 3, [0.3] * 3])] * 3)
    saved = dict(module.hparams)
    assert np.asarray(saved["loop_lengths"]).tolist() == [[12, 20], [13, 20], [14, 20]]
    module.on_load_checkpoint({"hyper_parameters": saved})
    other = {**saved, "loop_lengths": [[12, 20], [13, 21], [14, 20]]}
    with pytest.raises(CheckpointMismatchError, match="boundary vertex counts differ") as info:
        module.on_load_checkpoint({"hyper_parameters": other})
    assert "\n" not in str(info.value)
