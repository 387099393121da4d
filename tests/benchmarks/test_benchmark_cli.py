"""The benchmark scripts' refusals (grid_solver.py, curve_margin.py, dense_curves.py, final_evaluation_cost.py): an
impossible argument or an unusable checkpoint ends the script with one sentence on stderr and status 2 before
anything is measured, never a traceback or a nonsense number."""

from __future__ import annotations

import json

import pytest
import torch
from conftest import QUIET_CPU, TINY_EVAL, TINY_NET, compose_cfg, load_benchmark
from omegaconf import OmegaConf

from deepcurrents.experiments.runner import build, train
from deepcurrents.models.base import CHECKPOINT_KEY
from deepcurrents.models.loading import load_module


def refused(monkeypatch, capsys, script: str, argv: list[str]) -> str:
    """Runs ``script``'s main() with ``argv``; asserts status 2 and no traceback. → the last stderr line."""
    bench = load_benchmark(script)
    monkeypatch.setattr("sys.argv", [f"{script}.py", *argv])
    with pytest.raises(SystemExit) as info:
        bench.main()
    err = capsys.readouterr().err
    assert info.value.code == 2 and "Traceback" not in err, err
    return err.strip().splitlines()[-1]


@pytest.mark.parametrize(("script", "argv", "sentence"), [
    ("grid_solver", ["--resolutions", "0"], "--resolutions 0 must be at least 4."),
    ("grid_solver", ["--resolutions", "16", "-4"], "--resolutions -4 must be at least 4."),
    ("grid_solver", ["--iterations", "0"], "--iterations 0 must be at least 1."),
    ("grid_solver", ["--iterations", "-2"], "--iterations -2 must be at least 1."),
    ("grid_solver", ["--repeats", "0"], "--repeats 0 must be at least 1."),
    ("grid_solver", ["--threads", "0"], "--threads 0 must be at least 1."),
    ("grid_solver", ["--device", "foo"], "--device 'foo' is not a device"),
    ("grid_solver", ["--device", "cuda"], "--device cuda needs a CUDA GPU, and this machine has none"),
    ("curve_margin", ["--extents", "0"], "--extents 0.0 must be in (0, 1)"),
    ("curve_margin", ["--extents", "0.5", "-0.5"], "--extents -0.5 must be in (0, 1)"),
    ("curve_margin", ["--extents", "1.5"], "--extents 1.5 must be in (0, 1)"),
    ("curve_margin", ["--cells", "0"], "--cells 0 must be at least 1."),
    ("curve_margin", ["--iterations", "0"], "--iterations 0 must be at least 1."),
    ("curve_margin", ["--vertices", "2"], "--vertices 2 must be at least 3."),
    ("curve_margin", ["--tol", "0"], "--tol 0.0 must be greater than 0.0."),
    ("dense_curves", ["--vertices", "100", "2"], "--vertices 2 must be at least 3."),
    ("dense_curves", ["--resampled", "0"], "--resampled 0 must be at least 3."),
    ("dense_curves", ["--repeats", "0"], "--repeats 0 must be at least 1."),
    ("dense_curves", ["--max-pairs", "0"], "--max-pairs 0.0 must be at least 1."),
    ("final_evaluation_cost", ["x.ckpt", "--threads", "0"], "--threads 0 must be at least 1."),
    ("final_evaluation_cost", ["x.ckpt", "--mass-refine", "-1"], "--mass-refine -1 must be at least 1."),
    ("final_evaluation_cost", ["x.ckpt", "--mass-tube-radius", "-0.5"], "--mass-tube-radius -0.5 must be at least 0"),
])
def test_impossible_arguments_are_one_sentence(monkeypatch, capsys, script, argv, sentence):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)  # the CUDA case reads the same on a GPU machine
    assert sentence in refused(monkeypatch, capsys, script, argv)


def test_final_evaluation_cost_refuses_an_unusable_checkpoint_in_one_sentence(tmp_path, monkeypatch, capsys):
    """A missing file, a run folder and the grid method's checkpoint (no network to time): the loader's sentence
    (or one naming the kind of run) on stderr, status 2. The grid checkpoint is a crafted file naming the class."""
    grid = tmp_path / "grid.ckpt"
    torch.save({"state_dict": {}, CHECKPOINT_KEY: {"module": "deepcurrents.baselines.grid.GridModule"}}, grid)
    (tmp_path / "run" / "checkpoints").mkdir(parents=True)
    for argv, sentence in [
        ([str(tmp_path / "nope.ckpt")], "does not exist."),
        ([str(tmp_path / "run")], "is a directory, not a checkpoint file"),
        ([str(grid)], "is the grid method's checkpoint (experiment=minimal_grid) (GridModule), but this needs a "
                      "minimal surface's checkpoint"),
    ]:
        line = refused(monkeypatch, capsys, "final_evaluation_cost", argv)
        assert line.startswith("error: ckpt_path=") and sentence in line, line


@pytest.mark.slow
def test_final_evaluation_cost_times_a_reconstruction_with_its_own_losses(tmp_path, monkeypatch, capsys, cap_file):
    """A reconstruction's checkpoint is a CurrentModule too: its training step is timed with its own losses (the
    metric, the surface hinge and, under preset=cpu, the level hinge: ``compute_losses``) and its UCD reported beside
    the seconds."""
    cfg = compose_cfg(["experiment=recon_mesh", f"data.mesh={cap_file}", *TINY_NET, *QUIET_CPU, *TINY_EVAL,
                       "data.num_surface_samples=64", "data.num_workers=0", "trainer.max_steps=3"])
    trained = train(cfg, out_dir=tmp_path / "run")
    bench = load_benchmark("final_evaluation_cost")
    module = load_module(str(tmp_path / "run" / "checkpoints" / "last.ckpt"))
    batch = next(iter(build(OmegaConf.create(module.run_config))[0].train_dataloader()))
    assert set(module.compute_losses(batch)) >= {"loss", "current_loss", "surface_loss"}
    from deepcurrents.models.reconstruction import ReconstructionModule

    timed = []  # the losses of every timed step: the benchmark's steps must be the module's own
    own = ReconstructionModule.compute_losses
    monkeypatch.setattr(ReconstructionModule, "compute_losses",
                        lambda self, batch: timed.append(own(self, batch)) or timed[-1])
    monkeypatch.setattr("sys.argv", ["final_evaluation_cost.py", str(tmp_path / "run" / "checkpoints" / "last.ckpt")])
    bench.main()
    assert len(timed) == 2 * (30 + 5) and all({"surface_loss", "level_loss"} <= set(t) for t in timed)
    line = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert line["steps"] == 3 and line["seconds_per_step"] > 0 and 0 < line["evaluation_per_train"] < float("inf")
    assert line["ucd"] == pytest.approx(trained["ucd"], rel=1e-6)  # the run's own final evaluation, again
    assert "mass_area_sharpened" not in line  # a key the run does not write is left out, not null
