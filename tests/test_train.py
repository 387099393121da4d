"""The entry point end to end at tiny sizes: configs compose, runs write their files, resume continues,
bad input stops before training with one sentence."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import CONF_DIR, ROOT
from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from omegaconf import OmegaConf

from deepcurrents.errors import UserInputError
from deepcurrents.experiments.runner import build, train

TINY = [
    "logger=none", "preset=cpu", "trainer=cpu", "trainer.max_steps=6", "trainer.enable_progress_bar=false",
    "trainer.enable_model_summary=false", "data.num_samples=64", "model.rff.num_frequencies=16",
    "model.net.width=16", "model.net.depth=2", "evaluation.mass_samples=4096", "evaluation.mesh.resolution=24",
    "callbacks.model_checkpoint.every_n_train_steps=3",
]


def compose_cfg(overrides):
    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        return compose(config_name="train", overrides=overrides)


def config_choices():
    """Every option of every config group (experiments separately)."""
    conf = Path(CONF_DIR)
    groups = {}
    for group_dir in sorted(p for p in conf.rglob("*") if p.is_dir()):
        rel = group_dir.relative_to(conf).as_posix()
        if rel.startswith("hydra") or rel == "preset_sizes":  # preset_sizes is chosen by preset × data
            continue
        options = sorted(p.stem for p in group_dir.glob("*.yaml"))
        if options:
            groups[rel] = options
    return groups


def all_overrides():
    cases = []
    for group, options in config_choices().items():
        for opt in options:
            if group == "experiment":
                cases.append([f"experiment={opt}"])
            elif group in ("trainer", "logger", "preset", "data", "model", "callbacks", "paths"):
                cases.append([f"{group}={opt}"])
            else:  # groups added by experiments' families (ablation, hparams_search, ...)
                in_defaults = group in ("ablation", "hparams_search")  # in train.yaml's defaults: no '+'
                cases.append([f"{group}={opt}"] if in_defaults else [f"+{group}={opt}"])
    return cases


@pytest.mark.parametrize("overrides", all_overrides(), ids=lambda o: " ".join(o))
def test_every_config_composes(overrides):
    extra = [] if any(o.startswith("preset=") for o in overrides) else ["preset=cpu"]
    cfg = compose_cfg(overrides + extra)
    # every interpolation that does not need a running Hydra resolves
    for key in ("model", "data", "trainer", "evaluation"):
        if key in cfg and cfg[key] is not None:
            OmegaConf.to_container(cfg[key], resolve=True, throw_on_missing=False)


def test_paper_settings_of_minimal_experiments():
    cfg = compose_cfg(["experiment=minimal_trefoil"])
    assert cfg.trainer.max_steps == 100_000 and cfg.data.num_samples == 4096
    assert cfg.model.optim.lr == 5e-4 and cfg.model.optim.step_size == 10_000 and cfg.model.optim.gamma == 0.6
    assert cfg.model.rff.num_frequencies == 1024 and cfg.model.net.width == 256 and cfg.model.net.depth == 4


def test_train_writes_metrics_mesh_checkpoint_and_resumes(tmp_path):
    out = tmp_path / "run"
    cfg = compose_cfg(["experiment=minimal_trefoil", *TINY])
    metrics = train(cfg, out_dir=out)
    for name in ("metrics.json", "mesh.ply", "mesh.png", "checkpoints/last.ckpt"):
        assert (out / name).is_file(), name
    saved = json.loads((out / "metrics.json").read_text())
    assert saved["steps"] == 6 and saved == json.loads(json.dumps(metrics))
    for key in ("loss", "mass_area", "mesh_area", "boundary_error", "train_seconds"):
        assert key in saved
    ckpt = torch.load(out / "checkpoints/last.ckpt", weights_only=False)
    assert ckpt["deepcurrents"]["module"].endswith("CurrentModule")
    assert ckpt["deepcurrents"]["config"]["data"]["curve"] == "trefoil"
    # resume: the step count continues from the checkpoint
    cfg2 = compose_cfg(["experiment=minimal_trefoil", *TINY, "trainer.max_steps=9",
                        f"ckpt_path={out / 'checkpoints/last.ckpt'}"])
    resumed = train(cfg2, out_dir=tmp_path / "resumed")
    assert resumed["steps"] == 9
    assert not list((out / "checkpoints").glob("*.tmp"))


def test_2d_run_writes_curve_and_picture(tmp_path):
    cfg = compose_cfg(["experiment=minimal_2d", *TINY])
    metrics = train(cfg, out_dir=tmp_path)
    assert (tmp_path / "current.png").is_file() and (tmp_path / "curve.npz").is_file()
    assert "mass_length" in metrics and "curve_length" in metrics


def bad_obj(tmp_path):
    path = tmp_path / "open.obj"
    path.write_text("v 0 0 0\nv 0.1 0 0\n")
    return path


@pytest.mark.parametrize(
    "overrides, message",
    [
        (["data.curve=/nonexistent/curve.obj"], "does not exist"),
        (["data.curve=spiral"], "neither a known curve"),
        (["model.optim.lr=-1"], "lr"),
        (["data.num_samples=0"], "num_samples"),
        (["trainer.max_steps=0"], "max_steps"),
        (["evaluation.mesh.resolution=2"], "resolution"),
        (["evaluation.mesh.method=marching"], "evaluation.mesh.method"),
        (["model.net.width=0"], "width"),
        (["model.rff.sigma=-1"], r"model\.rff\.sigma"),
        (["model.rff.num_frequencies=0"], r"model\.rff\.num_frequencies"),
        (["+model.rff.frequencies=8"], "unknown keys"),
        (["model.net.activation=tanhh"], "activation"),
        (["ckpt_path=/nonexistent.ckpt"], "ckpt_path"),
    ],
)
def test_bad_input_stops_before_training_with_one_sentence(tmp_path, overrides, message):
    cfg = compose_cfg(["experiment=minimal_trefoil", *TINY, *overrides])
    with pytest.raises(UserInputError, match=message) as info:
        train(cfg, out_dir=tmp_path)
    assert "\n" not in str(info.value)
    assert not (tmp_path / "checkpoints").exists()


def test_cli_prints_one_sentence_without_traceback(tmp_path):
    bad = bad_obj(tmp_path)
    proc = subprocess.run(
        [sys.executable, str(ROOT / "train.py"), "experiment=minimal_curve", f"data.curve={bad}", "logger=none",
         f"hydra.run.dir={tmp_path / 'run'}"],
        capture_output=True, text=True, cwd=ROOT, timeout=120,
    )
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    err = [line for line in proc.stderr.splitlines() if line.startswith("error:")]
    assert len(err) == 1 and "open.obj" in err[0] and "at least 3" in err[0]


def test_nan_loss_stops_with_message_and_keeps_last_good_checkpoint(tmp_path, monkeypatch):
    from deepcurrents.errors import NonFiniteLossError
    from deepcurrents.models import current_module

    original = current_module.current_loss
    calls = {"n": 0}

    def poisoned(omega, metric=None):
        calls["n"] += 1
        loss = original(omega, metric)
        return loss * float("nan") if calls["n"] > 4 else loss

    monkeypatch.setattr(current_module, "current_loss", poisoned)
    cfg = compose_cfg(["experiment=minimal_trefoil", *TINY])
    with pytest.raises(NonFiniteLossError, match="step 4"):
        train(cfg, out_dir=tmp_path)
    ckpt = torch.load(tmp_path / "checkpoints/last.ckpt", weights_only=False)
    assert ckpt["global_step"] == 3
    assert all(torch.isfinite(v).all() for v in ckpt["state_dict"].values() if v.is_floating_point())


def test_datamodule_streams_differ_per_rank_and_resume_step():
    cfg = compose_cfg(["experiment=minimal_trefoil", *TINY])
    datamodule, _ = build(cfg)
    from deepcurrents.data import AmbientSamples

    a = next(iter(AmbientSamples(3, 8, seed=0, rank=0)))["x"]
    b = next(iter(AmbientSamples(3, 8, seed=0, rank=1)))["x"]
    c = next(iter(AmbientSamples(3, 8, seed=0, rank=0, start_step=5)))["x"]
    a2 = next(iter(AmbientSamples(3, 8, seed=0, rank=0)))["x"]
    assert torch.equal(a, a2) and not torch.equal(a, b) and not torch.equal(a, c)
    assert a.abs().max() <= 1 and np.isclose(datamodule.boundary.length(), datamodule.boundary.length())
