"""The entry point end to end at tiny sizes: runs write their files, resume continues, bad input stops before
training with one sentence. (Composing every config: test_configs.py.)"""

import json
import subprocess
import sys

import numpy as np
import pytest
import torch
from conftest import QUIET_CPU, ROOT, TINY_EVAL, TINY_NET, compose_cfg, written_curve_length

from deepcurrents.errors import UserInputError
from deepcurrents.experiments.runner import build, evaluation_threads, train, training_threads

TINY = [*QUIET_CPU, *TINY_NET, *TINY_EVAL, "trainer.max_steps=6", "callbacks.model_checkpoint.every_n_train_steps=3"]


def test_train_writes_metrics_mesh_checkpoint_and_resumes(tmp_path):
    out = tmp_path / "run"
    cfg = compose_cfg(["experiment=minimal_trefoil", *TINY])
    metrics = train(cfg, out_dir=out)
    for name in ("metrics.json", "mesh.ply", "mesh.png", "checkpoints/last.ckpt"):
        assert (out / name).is_file(), name
    saved = json.loads((out / "metrics.json").read_text())
    assert saved["steps"] == 6 and saved == json.loads(json.dumps(metrics))
    for key in ("loss", "mass_area", "mesh_area", "boundary_error", "train_seconds", "evaluation_seconds"):
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


def test_2d_run_writes_curve_and_picture(tmp_path, caplog):
    cfg = compose_cfg(["experiment=minimal_2d", *TINY])
    metrics = train(cfg, out_dir=tmp_path)
    assert (tmp_path / "current.png").is_file()
    written = written_curve_length(tmp_path / "curve.npz")  # curve_length is what the run wrote
    assert metrics["curve_length"] == pytest.approx(written, rel=1e-9) and written > 0
    # the mass bound never undercuts the minimal length: the segment between (-0.5, 0) and (0.5, 0), length 1
    assert metrics["mass_length"] > 1.0 - 4 * metrics["mass_length_stderr"]
    # extract on a 2D checkpoint: the curve's own settings take the app's values (they were dropped silently), the
    # surface-only ones are named as not used
    import logging

    from conftest import app_cfg

    from deepcurrents.cli.extract import ExtractConfig, extract_checkpoint

    ckpt = str(tmp_path / "checkpoints" / "last.ckpt")
    plain = extract_checkpoint(app_cfg(ExtractConfig, ckpt_path=ckpt, out_dir=str(tmp_path / "a")))
    assert plain["curve_length"] == pytest.approx(written, rel=1e-6)
    with caplog.at_level(logging.WARNING):
        tubed = extract_checkpoint(app_cfg(ExtractConfig, ckpt_path=ckpt, out_dir=str(tmp_path / "b"),
                                           boundary_tube=0.3, format="obj", close_boundary=False))
    assert tubed["curve_length"] != plain["curve_length"]
    assert "format" in caplog.text and "close_boundary" in caplog.text and "not used" in caplog.text


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
        (["torch_threads=many"], "torch_threads"),
        (["model.net.matmul_precision=low"], r"model\.net\.matmul_precision"),
        (["ckpt_path=/nonexistent.ckpt"], "ckpt_path"),
    ],
)
def test_bad_input_stops_before_training_with_one_sentence(tmp_path, overrides, message):
    cfg = compose_cfg(["experiment=minimal_trefoil", *TINY, *overrides])
    with pytest.raises(UserInputError, match=message) as info:
        train(cfg, out_dir=tmp_path)
    assert "\n" not in str(info.value)
    assert not (tmp_path / "checkpoints").exists()


def test_more_torch_threads_than_cores_is_said(monkeypatch, caplog):
    """torch_threads=999 on 2 cores ran 55x slower without a word."""
    import logging

    import lightning as L

    import deepcurrents.experiments.runner as runner

    monkeypatch.setattr(runner, "available_cores", lambda: 2)
    trainer = L.Trainer(accelerator="cpu", devices=1, logger=False, enable_progress_bar=False)
    with caplog.at_level(logging.WARNING):
        assert training_threads(compose_cfg(["torch_threads=999"]), trainer) == 999
        assert "torch_threads=999 is more than the 2 core(s)" in caplog.text
        caplog.clear()
        assert training_threads(compose_cfg(["torch_threads=2"]), trainer) == 2
        assert "torch_threads" not in caplog.text


def test_training_threads_leave_the_loader_workers_their_cores(monkeypatch):
    """torch_threads=auto on a CPU: each training process gets (cores // processes) − loader workers threads when
    that is fewer than torch's own choice; an integer is taken as given; null, or a run with cores to spare,
    keeps torch's choice. The families' CPU preset asks for auto; the other presets keep torch's choice."""
    import lightning as L

    import deepcurrents.experiments.runner as runner

    monkeypatch.setattr(runner, "available_cores", lambda: 2)
    monkeypatch.setattr(torch, "get_num_threads", lambda: 2)
    one, two = (L.Trainer(accelerator="cpu", devices=n, logger=False, enable_progress_bar=False) for n in (1, 2))

    def threads(trainer, **cfg):
        return training_threads(compose_cfg([f"{k}={v}" for k, v in cfg.items()]), trainer)

    assert threads(one, torch_threads="auto", **{"data.num_workers": 1}) == 1
    assert threads(one, torch_threads="auto", **{"data.num_workers": 0}) is None  # 2 cores: torch's 2 already
    assert threads(two, torch_threads="auto", **{"data.num_workers": 0}) == 1  # two DDP processes on 2 cores
    assert threads(one, torch_threads=3) == 3  # taken as given, with a warning: 3 threads on 2 cores wait on each other
    assert threads(one, torch_threads="null", **{"data.num_workers": 1}) is None
    # the final evaluation: an integer holds for the whole run, auto and null give torch's choice back
    assert evaluation_threads(compose_cfg(["torch_threads=1"])) == 1
    assert evaluation_threads(compose_cfg(["torch_threads=auto"])) is None
    assert evaluation_threads(compose_cfg([])) is None
    assert compose_cfg(["experiment=latent_hands", "preset=cpu"]).torch_threads == "auto"
    assert compose_cfg(["experiment=latent_heads", "preset=cpu"]).torch_threads == "auto"
    assert compose_cfg(["experiment=recon_hand", "preset=cpu"]).torch_threads is None
    monkeypatch.undo()  # the real setting: changed for the block, torch's choice again after it
    real = torch.get_num_threads()
    with runner.torch_threads(1):
        assert torch.get_num_threads() == 1
    assert torch.get_num_threads() == real


@pytest.mark.slow
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


def poison_the_loss(monkeypatch) -> dict:
    """The minimal-surface loss made NaN from its fifth call (step 4) on. → the call counter (set "n" to move it)."""
    from deepcurrents.models import current_module

    original = current_module.current_loss
    calls = {"n": 0}

    def poisoned(omega, metric=None, weight=None):
        calls["n"] += 1
        loss = original(omega, metric, weight)
        return loss * float("nan") if calls["n"] > 4 else loss

    monkeypatch.setattr(current_module, "current_loss", poisoned)
    return calls


def assert_last_good_checkpoint(run_dir, step: int) -> None:
    """The run's last.ckpt is the one of ``step`` and holds finite weights only."""
    ckpt = torch.load(run_dir / "checkpoints/last.ckpt", weights_only=False)
    assert ckpt["global_step"] == step
    assert all(torch.isfinite(v).all() for v in ckpt["state_dict"].values() if v.is_floating_point())


def test_nan_loss_stops_with_message_and_keeps_last_good_checkpoint(tmp_path, monkeypatch):
    from deepcurrents.errors import NonFiniteLossError

    calls = poison_the_loss(monkeypatch)
    cfg = compose_cfg(["experiment=minimal_trefoil", *TINY])
    with pytest.raises(NonFiniteLossError, match=r"step 4; training stopped, and the last good checkpoint is kept "
                                                 r"in .*checkpoints \(try a lower model\.optim\.lr\)\.$"):
        train(cfg, out_dir=tmp_path)
    assert_last_good_checkpoint(tmp_path, step=3)
    calls["n"] = 10  # NaN from the first step: it said a last good checkpoint was kept where none had been written
    with pytest.raises(NonFiniteLossError, match=r"step 0; training stopped, and no checkpoint had been written yet"):
        train(cfg, out_dir=tmp_path / "fresh")


@pytest.mark.parametrize("every", [2, 10])
def test_a_deferred_finiteness_check_names_the_step_and_keeps_the_last_good_checkpoint(tmp_path, monkeypatch, every):
    # read every 2 steps (step 4's NaN is read at step 5) or every 10 (read before the checkpoint of step 6 is
    # written, which is then not written): the same sentence and the same last good checkpoint as reading each step
    from deepcurrents.errors import NonFiniteLossError

    poison_the_loss(monkeypatch)
    cfg = compose_cfg(["experiment=minimal_trefoil", *TINY, f"model.optim.check_every={every}"])
    with pytest.raises(NonFiniteLossError, match=r"^The loss became nan at step 4; training stopped, and the last "
                                                 r"good checkpoint is kept in .*checkpoints"):
        train(cfg, out_dir=tmp_path)
    assert_last_good_checkpoint(tmp_path, step=3)


def test_a_deferred_check_changes_no_number_of_a_finite_run(tmp_path):
    runs = {}
    for every in (1, 7):
        cfg = compose_cfg(["experiment=minimal_trefoil", *TINY, f"model.optim.check_every={every}"])
        train(cfg, out_dir=tmp_path / str(every))
        runs[every] = torch.load(tmp_path / str(every) / "checkpoints/last.ckpt", weights_only=False)["state_dict"]
    assert all(torch.equal(runs[1][k], runs[7][k]) for k in runs[1])


def test_datamodule_streams_differ_per_rank_and_resume_step():
    cfg = compose_cfg(["experiment=minimal_trefoil", *TINY])
    datamodule, _ = build(cfg)
    from deepcurrents.data import AmbientSamples

    a = next(iter(AmbientSamples(3, 8, seed=0, rank=0)))["x"]
    b = next(iter(AmbientSamples(3, 8, seed=0, rank=1)))["x"]
    c = next(iter(AmbientSamples(3, 8, seed=0, rank=0, start_step=5)))["x"]
    a2 = next(iter(AmbientSamples(3, 8, seed=0, rank=0)))["x"]
    assert torch.equal(a, a2) and not torch.equal(a, b) and not torch.equal(a, c)
    assert a.abs().max() <= 1
    # the DataModule's boundary is the authors' trefoil, 100 vertices: (sin t + 2 sin 2t, cos t − 2 cos 2t, −sin 3t)/6
    t = 2 * np.pi * np.arange(100) / 100
    trefoil = np.stack([np.sin(t) + 2 * np.sin(2 * t), np.cos(t) - 2 * np.cos(2 * t), -np.sin(3 * t)], 1) / 6
    closed_length = np.linalg.norm(np.roll(trefoil, -1, axis=0) - trefoil, axis=1).sum()
    assert datamodule.boundary.length() == pytest.approx(closed_length, rel=1e-5)


def test_delayed_phase_harmonics_follow_the_budget_and_travel_in_checkpoints(tmp_path):
    """model.net.phase_harmonics_start: the harmonics' gate is 0 until that fraction of the budget, then opens over
    the next 0.2; the checkpoint carries it, so it evaluates (and resumes) with the gate it trained under. The run
    goes through the final evaluation (mass, phase mesh, sharpened bound) with harmonics in f."""
    from deepcurrents.models.loading import load_module

    cfg = compose_cfg(["experiment=minimal_trefoil", *TINY, "model.net.phase_harmonics=2",
                       "model.net.phase_harmonics_start=0.7"])
    metrics = train(cfg, out_dir=tmp_path / "run")
    assert metrics["mass_area"] > 0
    state = torch.load(tmp_path / "run/checkpoints/last.ckpt", weights_only=True)["state_dict"]
    current = load_module(tmp_path / "run/checkpoints/last.ckpt").current
    assert current.mlp.net[-1].out_features == 5
    # the last step (global step 5 of 6) trained under the gate at 5/6 of the budget: (5/6 − 0.7) / 0.2
    assert float(state["current.harmonic_gate"]) == pytest.approx((5 / 6 - 0.7) / 0.2)
    assert float(current.harmonic_gate) == pytest.approx((5 / 6 - 0.7) / 0.2)
    current.set_progress(0.5)
    assert float(current.harmonic_gate) == 0.0
    current.set_progress(0.95)
    assert float(current.harmonic_gate) == 1.0
    with pytest.raises(UserInputError, match=r"model.net.phase_harmonics_start=1.5 must be a fraction"):
        build(compose_cfg(["experiment=minimal_trefoil", *TINY, "model.net.phase_harmonics=2",
                           "model.net.phase_harmonics_start=1.5"]))


def test_coarse_to_fine_features_follow_the_budget_and_travel_in_checkpoints(tmp_path):
    """model.rff.coarse_to_fine: each step's weights are set from the budget used (step / max_steps here); the
    checkpoint carries them, so a checkpoint evaluates (and resumes) with the weights it trained under."""
    from deepcurrents.models.loading import load_module

    cfg = compose_cfg(["experiment=minimal_trefoil", *TINY, "model.rff.coarse_to_fine=1.0"])
    train(cfg, out_dir=tmp_path / "run")
    state = torch.load(tmp_path / "run/checkpoints/last.ckpt", weights_only=True)["state_dict"]
    encoding = load_module(tmp_path / "run/checkpoints/last.ckpt").current.encoding
    expected = encoding.weights.clone()
    encoding.set_progress(5 / 6)  # the last step (global step 5 of 6) trained under these
    torch.testing.assert_close(expected, encoding.weights)
    torch.testing.assert_close(state["current.encoding.weights"], expected)
    assert float(expected.mean()) < 1  # not every frequency is open at 5/6 of a budget that opens them over all of it
    with pytest.raises(UserInputError, match=r"model.rff.coarse_to_fine=2.0 must be a fraction"):
        build(compose_cfg(["experiment=minimal_trefoil", *TINY, "model.rff.coarse_to_fine=2"]))


def test_the_progress_bar_names_the_run_not_an_epoch_of_minus_two(tmp_path):
    """A run is one epoch of max_steps batches (max_epochs=-1): Lightning's rich bar said "Epoch 0/-2"."""
    from lightning.pytorch.callbacks.progress import ProgressBar

    from deepcurrents.experiments.runner import build_callbacks

    cfg = compose_cfg(["experiment=minimal_trefoil", "callbacks.media=null"])
    bars = [cb for cb in build_callbacks(cfg, tmp_path) if isinstance(cb, ProgressBar)]
    assert len(bars) == 1 and bars[0]._get_train_description(0).strip() == "Training"
    quiet = compose_cfg(["experiment=minimal_trefoil", "callbacks.media=null", "trainer.enable_progress_bar=false"])
    assert not any(isinstance(cb, ProgressBar) for cb in build_callbacks(quiet, tmp_path))


def test_init_from_starts_the_network_from_another_run_with_its_own_boundary(tmp_path):
    from deepcurrents.models.loading import CheckpointError, warm_start

    first = tmp_path / "first"
    train(compose_cfg(["experiment=minimal_trefoil", *TINY]), out_dir=first)
    ckpt = first / "checkpoints/last.ckpt"
    saved = torch.load(ckpt, weights_only=True)["state_dict"]
    _, module = build(compose_cfg(["experiment=minimal_curve", "data.curve=hopf", *TINY]))
    assert warm_start(module, ckpt) > 0
    state = module.state_dict()
    network = [k for k in saved if k.startswith("current.") and k != "current.vertices" and k != "current.loop_sizes"]
    assert network and all(torch.equal(state[k], saved[k]) for k in network)
    assert state["current.vertices"].shape != saved["current.vertices"].shape  # Γ is the Hopf link's, not the trefoil's
    # a run started from it counts its own steps
    warm = train(compose_cfg(["experiment=minimal_curve", "data.curve=hopf", *TINY, f"init_from={ckpt}"]),
                 out_dir=tmp_path / "warm")
    assert warm["steps"] == 6
    wider = [*TINY, "model.net.width=24"]
    _, other = build(compose_cfg(["experiment=minimal_trefoil", *wider]))
    with pytest.raises(CheckpointError, match=r"has a network of other settings \(current\.mlp"):
        warm_start(other, ckpt)


def test_a_suites_common_overrides_come_before_each_members_own_and_the_command_line_last():
    """suite.common reaches every member first, so a member's own and then the command line's overrides win (a user
    can run experiment=stitched_body model.surface_weight=1 to see the paper's weight)."""
    from omegaconf import OmegaConf

    from deepcurrents.experiments.runner import member_overrides

    member = OmegaConf.create({"name": "torso", "overrides": ["data.mesh=t.ply", "model.surface_weight=3"]})
    got = member_overrides(member, ["model.surface_weight=1", "hydra.run.dir=x"],
                           ["experiment=recon_mesh", "model.surface_weight=5"])
    assert got == ["experiment=recon_mesh", "model.surface_weight=5", "data.mesh=t.ply", "model.surface_weight=3",
                   "model.surface_weight=1"]
    cfg = compose_cfg(got)
    assert cfg.model.surface_weight == 1 and cfg.data.mesh == "t.ply"


@pytest.mark.slow
def test_suite_members_run_side_by_side_and_a_failing_one_is_named(tmp_path):
    """suite.jobs=2: members run as processes of their own (each `python -m deepcurrents.cli.train` with the cores
    shared out); their metrics come back in the suite's order, and a member that stops is named with its sentence."""
    from conftest import hydra_context
    from omegaconf import OmegaConf

    from deepcurrents.experiments.runner import available_cores, run_suite

    cfg = compose_cfg(["experiment=fig4"])
    tiny = [*TINY, "trainer.max_steps=3", "callbacks.media=null"]
    OmegaConf.set_struct(cfg, False)
    cfg.suite = {"jobs": 2, "report": "deepcurrents.experiments.tables.write_table",
                 "runs": [{"name": "trefoil", "overrides": ["experiment=minimal_trefoil", *tiny]},
                          {"name": "hopf", "overrides": ["experiment=minimal_hopf", *tiny]}]}
    with hydra_context():
        results = run_suite(cfg, tmp_path, extra_overrides=[])
    assert [r["name"] for r in results] == ["trefoil", "hopf"]
    assert all(r["metrics"]["steps"] == 3 for r in results)
    overrides = (tmp_path / "hopf" / ".hydra" / "overrides.yaml").read_text()
    assert f"torch_threads={max(1, available_cores() // 2)}" in overrides
    cfg.suite.runs.append({"name": "missing", "overrides": ["experiment=minimal_curve", "data.curve=nowhere.obj",
                                                              *tiny]})
    with hydra_context(), pytest.raises(UserInputError, match=r"^Suite member missing stopped: .*nowhere\.obj"):
        run_suite(cfg, tmp_path / "again", extra_overrides=[])


@pytest.mark.slow
def test_a_stitched_body_is_fitted_stitched_and_edited_from_its_checkpoints(tmp_path):
    """experiment=stitched_body on a three-part body at tiny sizes: every part runs, the report writes the stitched
    body; deepcurrents-edit-body then moves the shoulder: the limb and hand are carried rigidly (their meshes moved,
    not refitted), the torso is refitted from its checkpoint (init_from), and the edited body is stitched again."""
    from conftest import CHAIN, hydra_context, synthetic_body
    from omegaconf import OmegaConf

    from deepcurrents.data.body_edit import LoopMove
    from deepcurrents.data.body_partition import partition_body, write_body
    from deepcurrents.experiments.stitched import edit_body

    verts, faces, weights, names, _ = synthetic_body()
    folder = write_body(partition_body(verts * 0.4, faces, weights, names, parts=CHAIN), verts * 0.4, tmp_path / "b")
    tiny = [*TINY, "trainer.max_steps=4", "callbacks.media=null", "data.num_surface_samples=64"]
    cfg = compose_cfg(["experiment=stitched_body", f"suite.body={folder}", "suite.jobs=1"])
    OmegaConf.set_struct(cfg, False)
    cfg.suite.runs = [{"name": p.name, "overrides": [f"data.mesh={folder}/parts/{p.name}.ply", *tiny]} for p in CHAIN]
    with hydra_context():
        train(cfg, out_dir=tmp_path / "run")
    summary = json.loads((tmp_path / "run" / "stitched.json").read_text())
    assert summary["parts"] == 3
    assert (tmp_path / "run" / "body.ply").is_file() and (tmp_path / "run" / "body.png").is_file()
    edited = edit_body(tmp_path / "run", "shoulder", LoopMove(rotate=20.0), tmp_path / "edit", steps=2)
    assert edited["refit"] == ["torso"] and edited["moved_rigidly"] == ["limb", "hand"]
    overrides = (tmp_path / "edit" / "torso" / ".hydra" / "overrides.yaml").read_text()
    assert "init_from=" in overrides and "trainer.max_steps=2" in overrides
    assert json.loads((tmp_path / "edit" / "torso" / "metrics.json").read_text())["steps"] == 2
    # the carried limb is its first mesh moved by the rotation about the shoulder loop's centroid
    import trimesh

    from deepcurrents.data.body_partition import read_body

    body = read_body(folder)
    loop = next(v for n, _, v, _ in body.loops if n == "shoulder")
    before = trimesh.load(tmp_path / "run" / "limb" / "mesh.ply", process=False)
    after = trimesh.load(tmp_path / "edit" / "limb" / "mesh_body.ply", process=False)
    moved = LoopMove(rotate=20.0).apply(np.asarray(before.vertices), loop)
    np.testing.assert_allclose(after.vertices, moved, atol=1e-6)
    for name in ("body.ply", "body.png", "edit.png", "stitched.json", "body/loops.json"):
        assert (tmp_path / "edit" / name).is_file(), name


def test_a_stitched_body_without_its_loops_is_refused_before_any_part_trains(tmp_path):
    from conftest import hydra_context

    from deepcurrents.data.human_parts import DatasetError

    cfg = compose_cfg(["experiment=stitched_body", f"suite.body={tmp_path / 'nobody'}", *TINY])
    with hydra_context(), pytest.raises(DatasetError, match=r"has no loops\.json; run `make data`"):
        train(cfg, out_dir=tmp_path / "run")
    assert not (tmp_path / "run" / "torso").exists()
