"""Checkpoints of every model kind: they hold only tensors and plain data (read with weights_only=True), every
app opens them (render, extract, evaluate), a resumed run ends on the uninterrupted run's weights, and
``train_seconds`` in last.ckpt is the run's measured training time. A crafted checkpoint whose unpickling would
run a command is refused by every app in one sentence (exit status 2) and runs nothing."""

from __future__ import annotations

import json
import time
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
    app_cfg,
    compose_cfg,
    run_command_in_process,
    spherical_cap,
)
from omegaconf import OmegaConf

from deepcurrents.cli.evaluate import EvaluateConfig, evaluate_checkpoint
from deepcurrents.cli.extract import ExtractConfig, extract_checkpoint
from deepcurrents.cli.render import RenderConfig, render_checkpoint
from deepcurrents.experiments.runner import train
from deepcurrents.models.checkpointing import plain_data
from deepcurrents.models.loading import CheckpointError, load_module, read_checkpoint


def cap(height: float, centre=(0.0, 0.0, 0.0)) -> trimesh.Trimesh:
    return spherical_cap(radius=0.3, height=height, subdivisions=2, centre=centre)


@pytest.fixture(scope="module")
def shapes(tmp_path_factory) -> Path:
    """cap.ply (a reconstruction target) and family/ (two caps apart in space, a tiny family)."""
    root = tmp_path_factory.mktemp("shapes")
    cap(0.2).export(root / "cap.ply")
    (root / "family").mkdir()
    cap(0.2, centre=(-0.4, 0, 0)).export(root / "family" / "000_low.ply")
    cap(0.25, centre=(0.4, 0, 0)).export(root / "family" / "001_high.ply")
    return root


SMALL_TARGET = ["data.num_samples=64", "data.num_surface_samples=64", "data.num_workers=0"]
KINDS = {  # model kind → overrides of a tiny run ({shapes} is the fixture's folder)
    "current_3d": ["experiment=minimal_trefoil", *TINY_NET],
    "current_2d": ["experiment=minimal_2d", *TINY_NET],
    "grid": ["experiment=minimal_grid", "data.curve=circle", "model.grid.resolution=8"],
    "reconstruction": ["experiment=recon_mesh", "data.mesh={shapes}/cap.ply", *TINY_NET, *SMALL_TARGET],
    "closest_point": ["experiment=recon_mesh", "data.mesh={shapes}/cap.ply", "model=closest_point",
                      "+data.batch_kind=closest_point", *TINY_NET[1:], *SMALL_TARGET],
    "family": ["experiment=latent_hands", "data.path={shapes}/family", "data.meshes_per_batch=2",
               "data.augment=false", "model.latent_dim=8", "model.boundary_dim=8",
               *SMALL_TARGET],
}
EVERY_2 = ["callbacks.model_checkpoint.every_n_train_steps=2", "callbacks.model_checkpoint.save_top_k=-1"]


def kind_overrides(kind: str, shapes: Path, steps: int) -> list[str]:
    own = [o.replace("{shapes}", str(shapes)) for o in KINDS[kind]]
    return [*own, *QUIET_CPU, *TINY_EVAL, "evaluation.mesh.resolution=16", *EVERY_2, f"trainer.max_steps={steps}"]


@pytest.mark.slow
@pytest.mark.parametrize("kind", list(KINDS))
def test_every_kind_opens_in_every_app_and_resumes_exactly(kind, shapes, tmp_path):
    torch.manual_seed(0)
    run = tmp_path / "run"
    started = time.perf_counter()
    metrics = train(compose_cfg(kind_overrides(kind, shapes, 4)), out_dir=run)
    wall = time.perf_counter() - started
    assert metrics["steps"] == 4
    last, mid = run / "checkpoints" / "last.ckpt", run / "checkpoints" / "step0000002.ckpt"
    # plain data only, and the training clock: last.ckpt carries exactly the seconds metrics.json reports
    ckpt = torch.load(last, map_location="cpu", weights_only=True)
    assert ckpt["train_seconds"] == pytest.approx(metrics["train_seconds"], abs=1e-3)
    assert 0 < ckpt["train_seconds"] < wall
    # every app opens the step-2 checkpoint
    if kind == "closest_point":
        check_apps_refuse_a_model_without_current(str(mid), tmp_path)
    else:
        check_apps_open(str(mid), tmp_path, dim=2 if kind == "current_2d" else 3)
    # resume the step-2 checkpoint for two more steps: the same weights as the 4-step run
    resumed = train(compose_cfg([*kind_overrides(kind, shapes, 4), f"ckpt_path={mid}"]), out_dir=tmp_path / "resumed")
    assert resumed["steps"] == 4
    a = torch.load(last, weights_only=True)["state_dict"]
    b = torch.load(tmp_path / "resumed" / "checkpoints" / "last.ckpt", weights_only=True)["state_dict"]
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    # the resumed run's clock continues from the checkpoint's
    assert resumed["train_seconds"] >= torch.load(mid, weights_only=True)["train_seconds"]


def check_apps_open(ckpt_path: str, tmp_path: Path, dim: int) -> None:
    written = render_checkpoint(app_cfg(RenderConfig, ckpt_path=ckpt_path, out_dir=str(tmp_path / "render"),
                                        samples=4, grid=8, **{"camera.width": 12, "camera.height": 10}))
    assert written and all(Path(p).is_file() for p in written)
    summary = extract_checkpoint(app_cfg(ExtractConfig, ckpt_path=ckpt_path, out_dir=str(tmp_path / "extract"),
                                         resolution=16, picture=False))
    if dim == 3:
        mesh = trimesh.load(summary["mesh"], force="mesh")  # in the files' units, as the run's mesh.ply
        area = summary.get("mesh_area_input_units", summary["mesh_area"])  # a normalised reconstruction's key
        assert mesh.area == pytest.approx(area, rel=1e-6, abs=1e-12)
    else:  # the curve's polylines, and their length as the summary says
        curves = list(np.load(summary["curve"]).values())
        length = sum(float(np.linalg.norm(np.diff(c, axis=0), axis=1).sum()) for c in curves)
        assert len(curves) == summary["pieces"] and length == pytest.approx(summary["curve_length"])
    evaluated = evaluate_checkpoint(app_cfg(EvaluateConfig, ckpt_path=ckpt_path, out_dir=str(tmp_path / "eval"),
                                            resolution=16, samples=500, mass_samples=1024))
    assert json.loads((tmp_path / "eval" / "metrics.json").read_text()) == evaluated
    assert np.isfinite(evaluated["loss"]) and evaluated["steps"] == 2


def check_apps_refuse_a_model_without_current(ckpt_path: str, tmp_path: Path) -> None:
    """The closest-point baseline maps x to a point, it has no current: the apps say so in one sentence."""
    assert load_module(ckpt_path).global_step == 0  # it loads (apps need no trainer)
    for schema, body in ((RenderConfig, render_checkpoint), (ExtractConfig, extract_checkpoint),
                         (EvaluateConfig, evaluate_checkpoint)):
        with pytest.raises(CheckpointError, match="has no current to look at") as info:
            body(app_cfg(schema, ckpt_path=ckpt_path, out_dir=str(tmp_path / "app")))
        assert "\n" not in str(info.value)


def test_plain_data_turns_configs_and_arrays_into_plain_values():
    cfg = OmegaConf.create({"data": {"curve": "trefoil", "scale": [1, 2]}, "n": "${data.scale}"})
    out = plain_data({"cfg": cfg, "a": np.arange(3), "s": np.float32(0.5), "p": Path("/x/y"), "t": (1, "a")})
    assert out["cfg"] == {"data": {"curve": "trefoil", "scale": [1, 2]}, "n": [1, 2]}
    assert torch.equal(out["a"], torch.arange(3)) and out["s"] == 0.5 and out["p"] == "/x/y"
    assert out["t"] == (1, "a") and type(out["s"]) is float
    with pytest.raises(TypeError, match=r"checkpoint\['bad'\]\[0\] holds a .*object"):
        plain_data({"bad": [object()]})


@pytest.fixture(scope="module")
def crafted(tmp_path_factory, shapes) -> tuple[Path, Path]:
    """A real family checkpoint (the kind every app accepts) with a payload inside. → (file, marker)."""
    root = tmp_path_factory.mktemp("crafted")
    train(compose_cfg(kind_overrides("family", shapes, 1)), out_dir=root / "run")
    ckpt = torch.load(root / "run/checkpoints/last.ckpt", weights_only=True)
    marker = root / "MARKER"
    ckpt["hyper_parameters"]["note"] = Payload(f"touch {marker}")
    torch.save(ckpt, root / "shared.ckpt")
    return root / "shared.ckpt", marker


def test_crafted_checkpoint_is_refused_in_process(crafted):
    path, marker = crafted
    for opener in (read_checkpoint, load_module):
        with pytest.raises(CheckpointError, match=r"could run code") as info:
            opener(path)
        assert "posix.system" in str(info.value) and "\n" not in str(info.value)
    assert not marker.exists()


@pytest.mark.parametrize("app, args", [
    ("render", []), ("extract", []), ("evaluate", []), ("interpolate", []), ("generate", ["curve=circle"]),
])
def test_crafted_checkpoint_is_refused_by_every_app(crafted, tmp_path, app, args):
    path, marker = crafted
    proc = run_command_in_process(f"deepcurrents.cli.{app}",
                                  [f"ckpt_path={path}", f"out_dir={tmp_path / 'out'}", *args], cwd=ROOT)
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert "Traceback" not in proc.stderr
    errors = [line for line in proc.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "could run code" in errors[0] and "shared.ckpt" in errors[0]
    assert not marker.exists()


def test_a_full_disk_while_saving_keeps_the_previous_checkpoint(tmp_path, monkeypatch):
    import errno

    from deepcurrents.errors import UserInputError
    from deepcurrents.models import checkpointing

    path = tmp_path / "last.ckpt"
    checkpointing.atomic_torch_save({"step": 1}, path)

    def full(obj, fh):
        fh.write(b"partial")
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(checkpointing.torch, "save", full)
    with pytest.raises(UserInputError, match=r"could not be written \(No space left on device\) \(the previous one"):
        checkpointing.atomic_torch_save({"step": 2}, path)
    assert torch.load(path, weights_only=True) == {"step": 1}
    assert [p.name for p in tmp_path.iterdir()] == ["last.ckpt"]  # no temporary file left


@pytest.mark.parametrize("mask", [0o022, 0o077])
def test_a_checkpoint_gets_the_mode_any_new_file_gets(tmp_path, mask):
    """The temporary file's 0600 (mkstemp) must not outlive the rename: a shared checkpoint is readable by the group
    and others under the usual umask 022, and stays private under 077."""
    import os
    import stat

    from deepcurrents.models import checkpointing

    old = os.umask(mask)
    try:
        checkpointing.atomic_torch_save({"step": 1}, tmp_path / "last.ckpt")
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "last.ckpt").stat().st_mode) == 0o666 & ~mask
