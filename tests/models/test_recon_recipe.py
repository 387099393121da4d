"""The CPU reconstruction recipe (preset_sizes/data/cpu_recon_target.yaml): the target is normalised into the
paper's [-0.5, 0.5]^3 frame and the learning rate follows the budget; UCDs of runs in different frames are
compared in the target file's units (Table 1), the baseline's as well."""

from __future__ import annotations

import json

import pytest
from conftest import compose_cfg

from deepcurrents.experiments.recon_reports import table1_rows
from deepcurrents.experiments.runner import build, train

TINY = ["logger=none", "trainer=cpu", "data.num_workers=0", "evaluation.mass_samples=512",
        "evaluation.ucd_samples=1000", "evaluation.mesh.resolution=16", "data.num_samples=64",
        "data.num_surface_samples=64", "model.rff.num_frequencies=16", "model.net.width=16", "model.net.depth=1"]


@pytest.mark.parametrize("experiment", ["recon_hand", "recon_baseline"])
def test_cpu_preset_normalises_the_target_and_paper_keeps_the_authors_frame(experiment):
    cpu = compose_cfg([f"experiment={experiment}", "preset=cpu"])
    paper = compose_cfg([f"experiment={experiment}", "preset=paper"])
    # ours and the baseline see the same frame under each preset (a fair Table 1)
    assert cpu.data.normalize is True and paper.data.normalize == "auto"
    if experiment == "recon_hand":
        assert cpu.model.optim.schedule == "cosine" and paper.model.optim.schedule == "step"
        assert paper.model.optim.lr == 1e-3 and paper.model.optim.step_size == 2000
        assert cpu.model.level_weight == 1.0 and paper.model.level_weight == 0.0  # the authors' losses alone


def test_table1_compares_ucds_in_the_target_files_units():
    """A normalised run's ucd is in its own frame; the table takes ucd_input_units when there is one."""
    results = [
        {"name": "ours_hand", "metrics": {"ucd": 0.008, "ucd_input_units": 0.002, "ucd_reverse": 0.004,
                                          "ucd_reverse_input_units": 0.001, "train_seconds": 10.0}},
        {"name": "baseline_hand", "metrics": {"ucd": 0.003, "ucd_reverse": 0.005, "train_seconds": 10.0}},
    ]
    (row,) = table1_rows(results)
    assert row["ucd_ours"] == 0.002 and row["ucd_baseline"] == 0.003
    assert row["ucd_reverse_ours"] == 0.001 and row["ucd_reverse_baseline"] == 0.005


def test_table1_note_says_the_samples_used_and_a_baseline_that_stopped_short(tmp_path):
    """table1.md's note follows the run: its evaluation.ucd_samples, and a baseline that trained for less than
    our run's wall time is named (the note said 100k samples and equal time whatever the overrides were)."""
    from omegaconf import OmegaConf

    from deepcurrents.experiments.recon_reports import table1_report

    results = [
        {"name": "ours_hand", "metrics": {"ucd": 0.008, "train_seconds": 16.1}},
        {"name": "baseline_hand", "metrics": {"ucd": 0.009, "train_seconds": 0.5}},
        {"name": "ours_foot", "metrics": {"ucd": 0.007, "train_seconds": 20.0}},
        {"name": "baseline_foot", "metrics": {"ucd": 0.006, "train_seconds": 19.9}},
    ]
    table1_report(tmp_path, results, OmegaConf.create({"evaluation": {"ucd_samples": 5000}}))
    note = (tmp_path / "table1.md").read_text()
    assert "5,000 uniform samples" in note and "100k" not in note
    assert "stopped short of it on hand (" in note and "foot" not in note.split("stopped short")[1]


def test_table1_baselines_train_for_the_wall_time_whatever_the_command_line_limits():
    """The suite's baselines keep max_steps 1e6 after the command line's overrides (final_overrides), so that a
    trainer.max_steps given for the suite stops our runs but not the baselines' wall-time budget."""
    cfg = compose_cfg(["experiment=table1"])
    baselines = [m for m in cfg.suite.runs if m.name.startswith("baseline_")]
    assert len(baselines) == 4 and all(list(m.final_overrides) == ["trainer.max_steps=1000000"] for m in baselines)
    member = compose_cfg([*baselines[0].overrides, "preset=cpu", "trainer.max_steps=20",
                          *baselines[0].final_overrides])
    assert member.trainer.max_steps == 1000000 and member.model.wall_time_from.endswith("ours_head/metrics.json")


def test_baseline_reports_its_ucd_in_the_target_files_units(tmp_path, parts_root):
    overrides = ["experiment=recon_baseline", f"data.root={parts_root}", *TINY, "trainer.max_steps=3",
                 "data.normalize=true"]
    cfg = compose_cfg(overrides)
    datamodule, _ = build(cfg)
    metrics = train(cfg, out_dir=tmp_path / "run")
    assert datamodule.scale != 1.0
    assert metrics["ucd_input_units"] == pytest.approx(metrics["ucd"] * datamodule.scale, rel=1e-12)
    assert metrics["ucd_reverse_input_units"] == pytest.approx(metrics["ucd_reverse"] * datamodule.scale, rel=1e-12)
    assert json.loads((tmp_path / "run" / "metrics.json").read_text())["ucd_input_units"] > 0


def test_mass_weight_adds_the_euclidean_mass_of_the_same_samples(parts_root):
    """loss = L_curr(B) + λ·mean|ω| at the batch's ambient samples (+ the surface term), checked by hand."""
    cfg = compose_cfg(["experiment=recon_hand", f"data.root={parts_root}", *TINY, "model.mass_weight=0.25",
                       "model.surface_weight=0"])
    datamodule, module = build(cfg)
    datamodule.setup("fit")
    batch = next(iter(datamodule.train_dataloader()))
    loss = module.compute_losses(batch)["loss"].detach()
    _, omega = module.current(batch["x"], create_graph=False)
    metric_norm = (batch["metric"] @ omega.unsqueeze(-1)).squeeze(-1).norm(dim=-1).mean()
    assert float(loss) == pytest.approx(float(metric_norm + 0.25 * omega.norm(dim=-1).mean()), rel=1e-5)
    module.mass_weight = 0.0
    assert float(module.compute_losses(batch)["loss"].detach()) == pytest.approx(float(metric_norm), rel=1e-5)


def test_mass_weight_needs_uniform_ambient_samples(parts_root):
    from deepcurrents.errors import ConfigError
    from deepcurrents.experiments.config import validate_config

    cfg = compose_cfg(["experiment=recon_hand", "model.mass_weight=0.1", "data.sampling.kind=near"])
    with pytest.raises(ConfigError, match="model.mass_weight needs uniform ambient samples"):
        validate_config(cfg)
    with pytest.raises(ConfigError, match="model.mass_weight=-1"):
        build(compose_cfg(["experiment=recon_hand", f"data.root={parts_root}", *TINY, "model.mass_weight=-1"]))


def test_level_weight_adds_the_level_hinge_about_the_boundarys_level(parts_root):
    """loss = … + λ·E_y[(m − (f(y − εn/4) − s))^+ + (m + (f(y + εn/4) − s))^+], m = δ/4, s the mean of f over Γ by
    arc length (here a fine quadrature of its own, against the module's Γ points 0.01 apart); the term has a gradient
    and goes with level_weight = 0; a negative weight is refused in one sentence."""
    import torch

    from deepcurrents.errors import ConfigError

    cfg = compose_cfg(["experiment=recon_hand", f"data.root={parts_root}", *TINY, "model.level_weight=0.5"])
    datamodule, module = build(cfg)
    datamodule.setup("fit")
    batch = next(iter(datamodule.train_dataloader()))
    torch.manual_seed(0)
    with torch.no_grad():  # the output starts at zero (f ≡ 0, every hinge at 2m): a field that varies
        for p in module.current.parameters():
            p.add_(0.05 * torch.randn_like(p))
    losses = module.compute_losses(batch)
    with torch.no_grad():
        quadrature, lengths = [], []
        for loop in module.current.loops:
            a = loop.double()
            b = torch.roll(a, -1, 0)
            t = torch.linspace(0, 1, 201, dtype=torch.float64)[:-1] + 1 / 400  # midpoints of 200 pieces a side
            pts = (a[:, None] + t[None, :, None] * (b - a)[:, None]).reshape(-1, 3)
            quadrature.append(module.current.f(pts.float()).reshape(len(a), -1).mean(1))
            lengths.append((b - a).norm(dim=1))
        s = float((torch.cat(quadrature).double() * torch.cat(lengths)).sum() / torch.cat(lengths).sum())
        offset = (batch["epsilon"] / 4).unsqueeze(-1) * batch["surface_normals"]
        inner = module.current.f(batch["surface_points"] - offset).reshape(-1).double()
        outer = module.current.f(batch["surface_points"] + offset).reshape(-1).double()
        m = cfg.model.surface_margin / 4
        expected = float((torch.relu(m - (inner - s)) + torch.relu(m + (outer - s))).mean())
    assert 0 < expected and float(losses["level_loss"]) == pytest.approx(expected, rel=1e-3)
    assert float(losses["loss"]) == pytest.approx(float(losses["current_loss"]) + float(losses["surface_loss"])
                                                  + 0.5 * float(losses["level_loss"]), rel=1e-6)
    losses["level_loss"].backward()
    assert any(p.grad is not None and p.grad.abs().sum() > 0 for p in module.parameters())
    module.level_weight = 0.0
    assert "level_loss" not in module.compute_losses(batch)
    with pytest.raises(ConfigError, match="model.level_weight=-1"):
        build(compose_cfg(["experiment=recon_hand", f"data.root={parts_root}", *TINY, "model.level_weight=-1"]))
