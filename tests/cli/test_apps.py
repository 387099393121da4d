"""The checkpoint apps (render, extract, evaluate), checkpoint loading, the media callback, and the sweep /
launcher configs: on a tiny disk (circle boundary) trained once for the whole module."""

import json
import os
import pickle
import subprocess
import sys
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest
import torch
import trimesh
import yaml
from conftest import ROOT, app_cfg, compose_cfg
from hydra.utils import instantiate
from omegaconf import OmegaConf

from deepcurrents.cli.evaluate import EvaluateConfig, evaluate_checkpoint
from deepcurrents.cli.extract import ExtractConfig, extract_checkpoint
from deepcurrents.cli.render import RenderConfig, render_checkpoint
from deepcurrents.errors import ConfigError, UserInputError
from deepcurrents.experiments.runner import train
from deepcurrents.models import CurrentModule
from deepcurrents.models.loading import CheckpointError, load_module

RADIUS = 0.6  # data.curve=circle: the named circle of radius 0.6 in the xy-plane
DISK = [  # about the smallest setting whose extracted mesh is the disk (area within a few %)
    "experiment=minimal_curve", "data.curve=circle", "data.curve_vertices=48", "logger=csv", "preset=cpu",
    "trainer=cpu", "trainer.max_steps=200", "trainer.enable_progress_bar=false",
    "trainer.enable_model_summary=false", "data.num_samples=1024", "model.rff.num_frequencies=32",
    "model.net.width=64", "model.net.depth=2", "model.rff.sigma=1.0", "model.optim.lr=1e-2",
    "model.optim.step_size=150", "evaluation.mass_samples=8192", "evaluation.mesh.resolution=32",
    "callbacks.model_checkpoint.every_n_train_steps=100", "callbacks.media.every_n_steps=100",
    "callbacks.media.size=16", "callbacks.media.samples=6", "callbacks.media.grid=8",
]


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """A trained tiny disk: its run directory (metrics.json, mesh.ply, checkpoints/last.ckpt, media)."""
    out = tmp_path_factory.mktemp("disk")
    torch.manual_seed(0)
    train(compose_cfg(DISK), out_dir=out)
    return out


def test_run_leaves_media_files(run):
    assert (run / "render.png").is_file()  # the final render (MediaCallback.on_final_evaluation)
    assert (run / "media" / "render_step0000100.png").is_file()  # every_n_steps
    assert iio.imread(run / "render.png").shape == (16, 16, 3)


def test_the_logger_records_the_runs_whole_config(run):
    """The logged config is the run's (data, trainer, seed), in place of Lightning's record of the module's
    arguments, which lacked them and carried every vertex of Γ."""
    logged = yaml.safe_load((run / "csv" / "version_0" / "hparams.yaml").read_text())
    assert logged["data"]["curve"] == "circle" and logged["trainer"]["max_steps"] == 200 and logged["seed"] == 0
    assert "boundary" not in logged


def test_a_suite_members_wandb_run_is_named_and_grouped_by_the_suite(tmp_path):
    from deepcurrents.experiments.loggers import build_logger

    cfg = compose_cfg(["experiment=minimal_trefoil", "logger=wandb"])
    logger = build_logger(cfg, tmp_path / "suite" / "no_rff", member="no_rff")
    assert logger._wandb_init["name"] == "minimal_trefoil/no_rff"
    assert logger._wandb_init["group"] == str(tmp_path / "suite")
    cfg.logger.group = "mine"
    assert build_logger(cfg, tmp_path / "suite" / "no_rff", member="no_rff")._wandb_init["group"] == "mine"


def test_load_module_rebuilds_the_model_with_its_config(run):
    module = load_module(run / "checkpoints" / "last.ckpt")
    assert isinstance(module, CurrentModule) and not module.training
    assert module.run_config["data"]["curve"] == "circle" and module.loaded_step == 200
    x = torch.rand(64, 3) * 2 - 1
    ckpt = torch.load(run / "checkpoints" / "last.ckpt", weights_only=False)
    fresh = CurrentModule(**ckpt["hyper_parameters"])
    fresh.load_state_dict(ckpt["state_dict"])
    assert torch.equal(module.current.evaluate(x)[1], fresh.current.evaluate(x)[1])


def test_bad_checkpoints_are_one_sentence(run, tmp_path):
    good = run / "checkpoints" / "last.ckpt"
    with pytest.raises(CheckpointError, match="does not exist"):
        load_module(tmp_path / "missing.ckpt")
    truncated = tmp_path / "truncated.ckpt"
    truncated.write_bytes(good.read_bytes()[:2000])
    with pytest.raises(CheckpointError, match="truncated or corrupt"):
        load_module(truncated)
    # one byte changed inside a tensor's entry: torch.load read it without a word; the zip checksum catches it
    import struct
    import zipfile

    with zipfile.ZipFile(good) as archive:
        entry = max(archive.infolist(), key=lambda i: i.file_size)  # the largest tensor's bytes
    data = bytearray(good.read_bytes())
    name_len, extra_len = struct.unpack("<HH", data[entry.header_offset + 26: entry.header_offset + 30])
    data[entry.header_offset + 30 + name_len + extra_len + entry.file_size // 2] ^= 0xFF
    damaged = tmp_path / "damaged.ckpt"
    damaged.write_bytes(bytes(data))
    with pytest.raises(CheckpointError, match=rf"is corrupt: its entry '{entry.filename}' fails its checksum"):
        load_module(damaged)
    pickled = tmp_path / "pickled.ckpt"  # a plain pickle (not torch.save's archive) is refused unread
    pickled.write_bytes(pickle.dumps({"state_dict": {}}))
    with pytest.raises(CheckpointError, match="plain Python pickle"):
        load_module(pickled)
    foreign = tmp_path / "foreign.ckpt"
    torch.save({"state_dict": {}, "epoch": 0}, foreign)
    with pytest.raises(CheckpointError, match="not written by DeepCurrents"):
        load_module(foreign)
    ckpt = torch.load(good, weights_only=False)
    ckpt["deepcurrents"]["module"] = "deepcurrents.models.NoSuchModel"
    torch.save(ckpt, tmp_path / "unknown.ckpt")
    with pytest.raises(CheckpointError, match="does not have"):
        load_module(tmp_path / "unknown.ckpt")

    from deepcurrents.models.autodecoder import AutodecoderModule

    with pytest.raises(CheckpointError, match=r"is a minimal surface's checkpoint \(experiment=minimal_\*\) "
                                              r"\(CurrentModule\), but this needs a family run's checkpoint"):
        load_module(good, expected=AutodecoderModule)
    run_dir = tmp_path / "run"
    (run_dir / "checkpoints").mkdir(parents=True)
    (run_dir / "checkpoints" / "last.ckpt").write_bytes(good.read_bytes())
    with pytest.raises(CheckpointError, match=r"is a directory, not a checkpoint file; this run's last one is "
                                              r"ckpt_path='.*last\.ckpt'"):
        load_module(run_dir)


def test_render_app_writes_stills_turntables_and_mesh_pictures(run, tmp_path):
    ckpt = str(run / "checkpoints" / "last.ckpt")
    small = {"camera.width": 20, "camera.height": 14, "samples": 6, "grid": 8}
    written = render_checkpoint(app_cfg(RenderConfig, ckpt_path=ckpt, **small))
    assert written == [run / "checkpoints" / "last" / "render.png"]  # beside the checkpoint
    assert iio.imread(written[0]).shape == (14, 20, 3)
    out = tmp_path / "tt"
    written = render_checkpoint(app_cfg(RenderConfig, ckpt_path=ckpt, out_dir=str(out), turntable=True, frames=4,
                                        mesh=True, resolution=16, **small))
    gif = out / "render_turntable.gif"
    assert gif in written and iio.imread(gif, index=None).shape[:3] == (4, 14, 20)
    assert iio.imread(out / "render_mesh_turntable.gif", index=None).shape[0] == 4
    with pytest.raises(ConfigError, match="frames=0 must be a positive integer"):
        render_checkpoint(app_cfg(RenderConfig, ckpt_path=ckpt, turntable=True, frames=0))
    with pytest.raises(ConfigError, match="camera.width"):
        render_checkpoint(app_cfg(RenderConfig, ckpt_path=ckpt, **{"camera.width": -3}))
    for bad in (0, -8, 4):  # 0 was a ZeroDivisionError in the meshing, -8 an empty mesh blamed on the current
        with pytest.raises(ConfigError, match=rf"^resolution={bad} must be an integer ≥ 8"):
            render_checkpoint(app_cfg(RenderConfig, ckpt_path=ckpt, mesh=True, resolution=bad))


def test_extract_at_two_resolutions_gives_areas_that_agree(run, tmp_path):
    ckpt = str(run / "checkpoints" / "last.ckpt")
    areas = []
    for resolution in (24, 40):
        summary = extract_checkpoint(app_cfg(ExtractConfig, ckpt_path=ckpt, out_dir=str(tmp_path),
                                             resolution=resolution, format="obj", picture=False))
        mesh = trimesh.load(summary["mesh"], force="mesh")
        assert Path(summary["mesh"]).name == f"mesh_r{resolution}.obj"
        assert mesh.area == pytest.approx(summary["mesh_area"], rel=1e-6)
        areas.append(summary["mesh_area"])
    assert areas[0] == pytest.approx(areas[1], rel=0.03)
    assert areas[1] == pytest.approx(np.pi * RADIUS**2, rel=0.15)  # the disk (+8% after 200 tiny steps)
    with pytest.raises(ConfigError, match="resolution=4"):
        extract_checkpoint(app_cfg(ExtractConfig, ckpt_path=ckpt, resolution=4))
    with pytest.raises(ConfigError, match=r"min_alignment=2.0 must be in \[-1, 1\]"):
        extract_checkpoint(app_cfg(ExtractConfig, ckpt_path=ckpt, min_alignment=2.0))
    # the meshing knobs reach extract_surface: keeping the specks never removes area
    loose = extract_checkpoint(app_cfg(ExtractConfig, ckpt_path=ckpt, out_dir=str(tmp_path / "loose"), resolution=40,
                                       picture=False, min_alignment=-1.0, min_component=0.0))
    assert loose["mesh_area"] >= areas[1] - 1e-9


def disk_mesh(z: float) -> trimesh.Trimesh:
    mesh = trimesh.creation.cylinder(radius=RADIUS, height=1.0, sections=64)
    top = mesh.faces[np.all(np.isclose(mesh.vertices[mesh.faces][..., 2], 0.5), axis=1)]
    disk = trimesh.Trimesh(mesh.vertices, top, process=True)
    disk.apply_translation([0, 0, z - 0.5])
    return disk


def test_evaluate_gives_the_known_distance_of_a_known_pair(run, tmp_path):
    ckpt = str(run / "checkpoints" / "last.ckpt")
    disk_mesh(0.0).export(tmp_path / "disk.ply")
    disk_mesh(0.05).export(tmp_path / "lifted.ply")
    metrics = evaluate_checkpoint(app_cfg(EvaluateConfig, ckpt_path=ckpt, out_dir=str(tmp_path / "eval"),
                                          mesh=str(tmp_path / "disk.ply"), target=str(tmp_path / "lifted.ply"),
                                          samples=2000, mass_samples=8192))
    # every point of the lifted disk lies 0.05 above the disk, and conversely
    assert metrics["ucd"] == pytest.approx(0.05, abs=1e-9)
    assert metrics["ucd_reverse"] == pytest.approx(0.05, abs=1e-9)
    assert metrics["chamfer"] == pytest.approx(0.05, abs=1e-9)
    assert metrics["mesh_area"] == pytest.approx(disk_mesh(0.0).area)
    assert json.loads((tmp_path / "eval" / "metrics.json").read_text()) == metrics
    # the run's own loss and mesh come back from its checkpoint alone
    own = evaluate_checkpoint(app_cfg(EvaluateConfig, ckpt_path=ckpt, out_dir=str(tmp_path / "own"),
                                      target=str(run / "mesh.ply"), samples=2000))
    trained = json.loads((run / "metrics.json").read_text())
    assert own["loss"] == pytest.approx(trained["loss"], rel=1e-6)
    assert own["mesh_area"] == pytest.approx(trained["mesh_area"], rel=1e-6)
    assert own["ucd"] < 1e-6
    with pytest.raises(UserInputError, match="target='.*nope.ply' does not exist"):
        evaluate_checkpoint(app_cfg(EvaluateConfig, ckpt_path=ckpt, target=str(tmp_path / "nope.ply")))


@pytest.mark.slow
def test_cli_prints_one_sentence_for_bad_input(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "deepcurrents.cli.extract", f"ckpt_path={tmp_path / 'x.ckpt'}"],
                          capture_output=True, text=True, cwd=tmp_path, timeout=300)
    assert proc.returncode == 2
    assert proc.stderr.strip() == f"error: ckpt_path='{tmp_path / 'x.ckpt'}' does not exist."
    assert not list(tmp_path.iterdir())  # no Hydra run directory, no logs left behind


def sweep_overrides(spec: dict) -> list[str]:
    """The Hydra overrides a W&B agent passes: the command's fixed ones and one value per parameter."""
    fixed = [a for a in spec["command"] if "=" in a and not a.startswith("${")]
    sampled = []
    for key, p in spec["parameters"].items():
        sampled.append(f"{key}={p['values'][0] if 'values' in p else p['min']}")
    return fixed + sampled


@pytest.mark.parametrize("path", sorted((ROOT / "sweeps").glob("*.yaml")), ids=lambda p: p.name)
def test_wandb_sweeps_compose(path):
    spec = yaml.safe_load(path.read_text())
    assert spec["program"] == "train.py" and (ROOT / spec["program"]).is_file()
    assert spec["command"][:3] == ["${env}", "python", "${program}"] and "${args_no_hyphens}" in spec["command"]
    assert spec["metric"]["name"].startswith("final/") and spec["metric"]["goal"] == "minimize"
    cfg = compose_cfg(sweep_overrides(spec))
    experiment = next(a.split("=", 1)[1] for a in spec["command"] if a.startswith("experiment="))
    assert cfg.task_name == experiment
    for key, p in spec["parameters"].items():  # every searched key is a real setting, and takes the value
        value = p["values"][0] if "values" in p else p["min"]
        assert OmegaConf.select(cfg, key) == pytest.approx(value), key


@pytest.mark.parametrize("search, experiment", [("minimal_optuna", "minimal_trefoil"),
                                                ("recon_optuna", "recon_hand")])
def test_optuna_searches_name_real_settings(search, experiment):
    cfg = compose_cfg([f"experiment={experiment}", f"hparams_search={search}"], hydra_config=True)
    assert cfg.hydra.sweeper._target_.endswith("OptunaSweeper") and cfg.hydra.sweeper.direction == "minimize"
    assert cfg.objective in ("mass_area", "ucd")
    for key in cfg.hydra.sweeper.params:
        assert OmegaConf.select(cfg, key) is not None, key


def test_slurm_launcher_composes():
    cfg = compose_cfg(["experiment=minimal_trefoil", "hydra/launcher=submitit_slurm", "hydra.launcher.partition=gpu",
                       "hydra.sweep.dir=/tmp/sweep"], hydra_config=True)
    launcher = instantiate(cfg.hydra.launcher)
    assert type(launcher).__name__ == "SlurmLauncher"
    assert launcher.params["partition"] == "gpu" and launcher.params["gpus_per_node"] == 1


# a multirun's jobs at a few seconds each
TINY_SWEEP = ["experiment=minimal_trefoil", "logger=none", "preset=cpu", "trainer=cpu", "trainer.max_steps=2",
              "trainer.enable_progress_bar=false", "trainer.enable_model_summary=false", "data.num_samples=32",
              "model.rff.num_frequencies=8", "model.net.width=8", "model.net.depth=1", "evaluation.mass_samples=1024",
              "evaluation.mesh.resolution=12", "callbacks.media=null"]


@pytest.mark.slow
def test_optuna_sweep_runs_two_tiny_trials(tmp_path):
    sweep = tmp_path / "sweep"
    proc = subprocess.run(
        [sys.executable, str(ROOT / "train.py"), "-m", "hparams_search=minimal_optuna", *TINY_SWEEP,
         "hydra.sweeper.n_trials=2", f"hydra.sweep.dir={sweep}",
         f"hydra.sweeper.storage=sqlite:///{tmp_path / 'optuna.db'}"],  # the README's way to keep a study
        capture_output=True, text=True, cwd=ROOT, timeout=600,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    values = [json.loads((sweep / str(i) / "metrics.json").read_text())["mass_area"] for i in (0, 1)]
    best = yaml.safe_load((sweep / "optimization_results.yaml").read_text())
    assert best["best_value"] == pytest.approx(min(values))
    table = (sweep / "table.md").read_text().splitlines()
    assert len(table) == 4 and table[0].startswith("| run | mass_area |")  # header, rule, two trials
    import optuna  # the study is in the database (optuna 2 with SQLAlchemy 2 failed here with an AssertionError)

    study = optuna.load_study(study_name="minimal_trefoil", storage=f"sqlite:///{tmp_path / 'optuna.db'}")
    assert len(study.trials) == 2 and study.best_value == pytest.approx(best["best_value"])


@pytest.mark.slow
def test_each_sweep_job_logs_its_own_wandb_run(tmp_path):
    """W&B keeps one run per process until it is finished, and Lightning's finalize does not finish it: every job
    after the first logged into job 0's run (its config and summary overwritten by the last job's, the last job's
    final rows dropped as out of order). Now each job has its own offline run."""
    sweep = tmp_path / "sweep"
    proc = subprocess.run(
        [sys.executable, str(ROOT / "train.py"), "-m", *TINY_SWEEP, "logger=wandb", "model.optim.lr=1e-3,3e-3",
         f"hydra.sweep.dir={sweep}"],
        capture_output=True, text=True, cwd=ROOT, timeout=600, env={**os.environ, "WANDB_MODE": "offline",
                                                                     "WANDB_SILENT": "true"},
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "already in progress" not in proc.stderr
    for job in ("0", "1"):
        assert len(list((sweep / job / "wandb").glob("offline-run-*"))) == 1, job  # job 1 had none


@pytest.mark.slow
def test_a_sweep_job_that_fails_ends_that_job_not_the_sweep(tmp_path):
    """A multirun with an impossible value among its options: the other jobs run (the failed one used to stop the
    sweep, with no table even for the jobs before it), table.md lists them and the failed job with its sentence,
    the job folder keeps the sentence in error.txt, and the multirun ends with one sentence and status 2."""
    sweep = tmp_path / "sweep"
    proc = subprocess.run(
        [sys.executable, str(ROOT / "train.py"), "-m", *TINY_SWEEP, "model.optim.lr=-1,3e-3",
         f"hydra.sweep.dir={sweep}"],
        capture_output=True, text=True, cwd=ROOT, timeout=600,
    )
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert "Traceback" not in proc.stderr
    assert (sweep / "1" / "metrics.json").is_file() and not (sweep / "0" / "metrics.json").exists()
    assert (sweep / "0" / "error.txt").read_text().strip() == "model.optim.lr=-1 must be positive."
    table = (sweep / "table.md").read_text()
    assert "\n| 1: model.optim.lr=" in table  # the one job that ran, named by what sets it apart from the failed one
    assert "- 0: model.optim.lr=-1: model.optim.lr=-1 must be positive." in table
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("error: 1 of 2 sweep jobs failed (job 0: model.optim.lr=-1 must be positive)"), last


def test_a_jobs_last_attempt_decides_whether_it_failed(tmp_path):
    """A requeued job, or a sweep run again into the same folder, keeps the other attempt's file: error.txt older
    than metrics.json is a result (the cli also clears error.txt when a job starts), metrics.json older than
    error.txt is a failure, not a row of the table."""
    import os

    from deepcurrents.experiments.multirun import collect_jobs, failed_jobs

    sentence = "model.optim.lr=-1 must be positive."
    attempts = (("0", ("error.txt", "metrics.json")), ("1", ("metrics.json", "error.txt")), ("2", ("error.txt",)))
    for num, order in attempts:
        (tmp_path / num).mkdir()
        for t, name in enumerate(order):
            (tmp_path / num / name).write_text("{}" if name == "metrics.json" else sentence)
            os.utime(tmp_path / num / name, (1000 + t, 1000 + t))
    assert [j["num"] for j in failed_jobs(tmp_path)] == ["1", "2"]
    assert [j["num"] for j in collect_jobs(tmp_path)] == ["0"]


def fake_hydra_config(state) -> type:
    """A stand-in for hydra.core.hydra_config.HydraConfig whose ``get()`` is ``state`` (a Hydra config node)."""
    return type("FakeHydraConfig", (), {"initialized": staticmethod(lambda: True), "get": staticmethod(lambda: state)})


def write_sweep_job(sweep: Path, num: str, overrides: str, name: str, text: str) -> None:
    """A sweep's job folder as a finished or failed job leaves it: its .hydra/overrides.yaml and ``name``."""
    (sweep / num / ".hydra").mkdir(parents=True)
    (sweep / num / ".hydra" / "overrides.yaml").write_text(overrides)
    (sweep / num / name).write_text(text)


@pytest.mark.parametrize("sweeper, stops", [
    ("hydra._internal.core_plugins.basic_sweeper.BasicSweeper", True),
    ("hydra_plugins.hydra_optuna_sweeper.optuna_sweeper.OptunaSweeper", False),
])
def test_failed_jobs_end_a_grid_sweep_with_status_2_but_not_a_search(tmp_path, capsys, sweeper, stops):
    """A grid sweep with a failed job ends with one sentence and status 2, whether or not it names an objective
    (its column first); an Optuna search warns and ends normally, its failed trials scored the worst value."""
    from deepcurrents.experiments.multirun import MultirunTable

    for num, name, text in (("0", "error.txt", "model.optim.lr=-1 must be positive."),
                            ("1", "metrics.json", json.dumps({"mass_area": 0.8}))):
        (tmp_path / num).mkdir()
        (tmp_path / num / name).write_text(text)
    config = OmegaConf.create({"objective": "mass_area", "hydra": {"sweep": {"dir": str(tmp_path)},
                                                                   "sweeper": {"_target_": sweeper}}})
    if stops:
        with pytest.raises(SystemExit) as info:
            MultirunTable().on_multirun_end(config)
        assert info.value.code == 2
        assert "error: 1 of 2 sweep jobs failed (job 0: model.optim.lr=-1 must be positive)" in capsys.readouterr().err
    else:
        MultirunTable().on_multirun_end(config)
    assert "- 0: " in (tmp_path / "table.md").read_text()


def test_a_sweep_whose_jobs_all_failed_still_lists_them_where_the_table_would_be(tmp_path, capsys):
    """Every trial failing wrote no table.md at all (the README says failed jobs are listed under the table)."""
    from deepcurrents.experiments.multirun import MultirunTable

    for num in ("0", "1"):
        write_sweep_job(tmp_path, num, f"- model.optim.lr=-{num}\n- preset=cpu\n", "error.txt",
                        f"model.optim.lr=-{num} must be positive.")
    config = OmegaConf.create({"hydra": {"sweep": {"dir": str(tmp_path)}, "sweeper": {"_target_": "optuna"}}})
    with pytest.raises(SystemExit):
        MultirunTable().on_multirun_end(config)
    assert (tmp_path / "table.md").read_text() == (
        "No job of this sweep finished.\n\nFailed jobs:\n\n- 0: model.optim.lr=-0: model.optim.lr=-0 must be "
        "positive.\n- 1: model.optim.lr=-1: model.optim.lr=-1 must be positive.\n")
    assert "error: 2 of 2 sweep jobs failed" in capsys.readouterr().err


def test_a_sweep_of_suites_with_a_failed_job_says_which_jobs_ran_suites(tmp_path, capsys):
    """A sweep of suites (their tables are in their own folders, no metrics.json at the job's level) with one failed
    job said "No job of this sweep finished", and a failed job whose overrides all jobs shared was listed as
    `- 1: : …`."""
    from deepcurrents.experiments.multirun import MultirunTable

    for num, name, text in (("0", "suite.json", "[]"), ("1", "error.txt", "data.index=1 is out of range.")):
        write_sweep_job(tmp_path, num, "- experiment=hand_ablation\n- data.index=1\n", name, text)
    (tmp_path / "table.csv").write_text("run,ucd\nstale,1\n")  # an earlier sweep's, into the same folder
    config = OmegaConf.create({"hydra": {"sweep": {"dir": str(tmp_path)}, "sweeper": {"_target_": "basic"}}})
    with pytest.raises(SystemExit):
        MultirunTable().on_multirun_end(config)
    assert (tmp_path / "table.md").read_text() == (
        "Jobs 0 ran suites (their tables are in their folders).\n\nFailed jobs:\n\n"
        "- 1: experiment=hand_ablation data.index=1: data.index=1 is out of range.\n")
    assert not (tmp_path / "table.csv").exists()
    assert "error: 1 of 2 sweep jobs failed" in capsys.readouterr().err


@pytest.mark.parametrize("direction, worst", [("minimize", float("inf")), ("maximize", float("-inf")),
                                              (["maximize"], float("-inf")), ("Direction.maximize", float("-inf")),
                                              (None, float("inf"))])
def test_a_failed_optuna_trial_scores_the_worst_value_for_the_direction(monkeypatch, direction, worst):
    import deepcurrents.cli.train as cli_train

    sweeper = OmegaConf.create({} if direction is None else {"direction": direction})
    monkeypatch.setattr(cli_train, "HydraConfig", fake_hydra_config(type("H", (), {"sweeper": sweeper})()))
    assert cli_train.worst_value() == worst
    assert cli_train.objective_value({"ucd": None}, "ucd") == worst  # an empty mesh's metric, written empty


def test_evaluate_draws_the_mass_as_the_run_did_with_the_mesh_cells_refined(tmp_path):
    """evaluation.mass_refine_mesh=true: the run's final evaluation and the evaluate app both refine the cells of the
    current's mesh (made first), so the app gives back the run's own loss."""
    torch.manual_seed(0)
    train(compose_cfg(DISK + ["evaluation.mass_refine_mesh=true"]), out_dir=tmp_path / "run")
    trained = json.loads((tmp_path / "run" / "metrics.json").read_text())
    own = evaluate_checkpoint(app_cfg(EvaluateConfig, ckpt_path=str(tmp_path / "run" / "checkpoints" / "last.ckpt"),
                                      out_dir=str(tmp_path / "own"), samples=2000))
    assert own["loss"] == pytest.approx(trained["loss"], rel=1e-9)
    assert trained["mass_evaluations"] > trained["mass_samples"]  # refined cells drew sub-samples


def test_apps_on_a_family_shape_write_beside_the_checkpoint_under_that_shape(tmp_path):
    """extract/render/evaluate with shape=1 and then shape=2 wrote the same files (each run replaced the other's,
    and no file said which shape it held): the default folder now ends in shape<i>; an out_dir is used as given."""
    from deepcurrents.cli.common import output_dir

    ckpt = tmp_path / "run" / "checkpoints" / "last.ckpt"
    assert output_dir(str(ckpt), None) == tmp_path / "run" / "checkpoints" / "last"
    assert output_dir(str(ckpt), None, shape=2) == tmp_path / "run" / "checkpoints" / "last" / "shape2"
    assert output_dir(str(ckpt), str(tmp_path / "mine"), shape=2) == tmp_path / "mine"
    assert (tmp_path / "run" / "checkpoints" / "last" / "shape2").is_dir()


@pytest.mark.parametrize("module", ["families", "common"])
def test_the_apps_helper_modules_are_not_commands_and_say_so(module):
    """`python -m deepcurrents.cli.families` (shared plumbing of interpolate and generate) exited 0 without a word."""
    done = subprocess.run([sys.executable, "-m", f"deepcurrents.cli.{module}"], capture_output=True, text=True,
                          cwd=ROOT, timeout=120)
    assert done.returncode == 2 and "Traceback" not in done.stderr
    assert done.stderr.startswith(f"error: deepcurrents.cli.{module} is shared plumbing of the apps, not a command")


@pytest.mark.parametrize("mode, sweeper, said", [
    ("RUN", "", "Continue with ckpt_path=auto hydra.run.dir=/runs/job."),
    ("MULTIRUN", "hydra._internal.core_plugins.basic_sweeper.BasicSweeper",
     "Continue the sweep with the same command plus ckpt_path=auto hydra.sweep.dir=/runs/sweep (each job"),
    ("MULTIRUN", "hydra_plugins.hydra_optuna_sweeper.optuna_sweeper.OptunaSweeper",
     "An Optuna search does not resume its trials"),
])
def test_a_stopped_jobs_hint_says_how_its_kind_of_run_continues(monkeypatch, mode, sweeper, said):
    """Ctrl-C in a multirun printed `ckpt_path=auto hydra.run.dir=<job dir>`, which under -m means nothing (the
    probe's attempt was refused: another config) and leaves the jobs after it unrun."""
    from hydra.types import RunMode

    import deepcurrents.experiments.runner as runner

    state = OmegaConf.create({"mode": mode, "sweep": {"dir": "/runs/sweep"}, "sweeper": {"_target_": sweeper}})
    state.mode = RunMode[mode]
    import deepcurrents.experiments.multirun as multirun

    monkeypatch.setattr(runner, "HydraConfig", fake_hydra_config(state))
    monkeypatch.setattr(multirun, "HydraConfig", fake_hydra_config(state))
    assert runner.continue_hint(Path("/runs/job")).startswith(said)


@pytest.mark.parametrize("launcher, trainer, refused", [
    ("hydra._internal.core_plugins.basic_launcher.BasicLauncher", ["trainer=ddp_cpu"], True),
    ("hydra._internal.core_plugins.basic_launcher.BasicLauncher", ["trainer=cpu", "trainer.devices=2"], True),
    ("hydra._internal.core_plugins.basic_launcher.BasicLauncher", ["trainer=cpu"], False),
    ("hydra._internal.core_plugins.basic_launcher.BasicLauncher",
     ["trainer=ddp_cpu", "trainer.strategy=ddp_spawn"], False),
    ("hydra_plugins.hydra_submitit_launcher.submitit_launcher.SlurmLauncher", ["trainer=ddp"], False),
])
def test_a_local_multirun_refuses_a_ddp_trainer(monkeypatch, launcher, trainer, refused):
    """-m with trainer=ddp_cpu on the local launcher: Lightning re-ran the command line, -m included, in its second
    process, which walked the whole sweep beside the first (a stray sweep folder, tables written twice)."""
    import deepcurrents.cli.train as cli_train

    state = OmegaConf.create({"launcher": {"_target_": launcher}})
    monkeypatch.setattr(cli_train, "HydraConfig", fake_hydra_config(state))
    cfg = compose_cfg(["experiment=minimal_trefoil", *trainer])
    if refused:
        with pytest.raises(ConfigError, match=r"^trainer\.devices=2 with trainer\.num_nodes=1 \(strategy \w+: DDP\) "
                                              r"cannot run inside a local multirun \(-m\)"):
            cli_train.check_local_ddp_sweep(cfg)
    else:
        cli_train.check_local_ddp_sweep(cfg)


def test_an_apps_stdout_is_its_json_summary_and_its_log_lines_go_to_stderr(run, tmp_path):
    """Warnings went to stdout between the printed JSON's lines, so `… | jq` and json.load failed on it."""
    from conftest import run_command_in_process

    proc = run_command_in_process("deepcurrents.cli.extract", [f"ckpt_path={run / 'checkpoints' / 'last.ckpt'}",
                                                            "resolution=12", f"out_dir={tmp_path}"], cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert json.loads(proc.stdout)["resolution"] == 12  # the whole of stdout is the summary
    assert "resolution=12 gives" in proc.stderr  # the coarse grid's warning
    # another of Hydra's logging choices replaces it whole (patching the chosen one's handler broke `disabled`)
    quiet = run_command_in_process("deepcurrents.cli.extract", [f"ckpt_path={tmp_path / 'none.ckpt'}",
                                                            "hydra/job_logging=disabled"], cwd=tmp_path)
    assert quiet.returncode == 2 and quiet.stderr.strip().endswith("does not exist.")
