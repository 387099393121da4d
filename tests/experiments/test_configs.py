"""The configs: every option of every group composes, resolves and names importable classes; every experiment
builds its DataModule and LightningModule (on small synthetic inputs); the lengths and sizes of every experiment
under preset=paper and preset=cpu are pinned; one `evaluation` node; recon_part and its per-part aliases."""

from __future__ import annotations

from functools import cache
from pathlib import Path

import pytest
import yaml
from conftest import CONF_DIR, QUIET_CPU, TINY_NET, compose_cfg, spherical_cap, write_oriented_cloud
from hydra.utils import get_object
from omegaconf import OmegaConf, open_dict

from deepcurrents.errors import UserInputError
from deepcurrents.experiments.config import validate_config
from deepcurrents.experiments.runner import build, member_overrides, train

CONF = Path(CONF_DIR)
EXPERIMENTS = sorted(p.stem for p in (CONF / "experiment").glob("*.yaml"))
# several runs and a report: their members are experiments
SUITES = ("fig4", "hand_ablation", "table1", "stitched_body")
PARTS = {"recon_head": "heads", "recon_hand": "hands", "recon_forearm": "forearms", "recon_arm": "arms",
         "recon_torso": "torsos", "recon_foot": "feet"}
# chosen by the defaults list (preset × data, preset × model), never on the command line
CHOSEN_BY_DEFAULTS = ("hydra", "preset_sizes")


@cache
def composed(*overrides: str):
    """compose_cfg with the `hydra` node (its group choices), once per distinct override list (read-only: tests
    share it)."""
    cfg = compose_cfg(list(overrides), hydra_config=True)
    OmegaConf.set_readonly(cfg, True)
    return cfg


def group_options() -> list[list[str]]:
    """One override per option of every config group but experiments (they are built below)."""
    cases = []
    for group_dir in sorted(p for p in CONF.iterdir() if p.is_dir()):
        group = group_dir.name
        if group in CHOSEN_BY_DEFAULTS or group == "experiment":
            continue
        cases += [[f"{group}={p.stem}"] for p in sorted(group_dir.glob("*.yaml"))]
    return cases


def targets(node, path: str = "") -> list[tuple[str, str]]:
    """Every (key, _target_) in a plain container."""
    found = []
    if isinstance(node, dict):
        if "_target_" in node:
            found.append((path or "<root>", node["_target_"]))
        for key, value in node.items():
            found += targets(value, f"{path}.{key}" if path else str(key))
    elif isinstance(node, list):
        for i, value in enumerate(node):
            found += targets(value, f"{path}[{i}]")
    return found


def assert_resolves(cfg) -> dict:
    """Every interpolation outside `hydra` resolves and every `_target_` imports. → the resolved container."""
    plain = OmegaConf.to_container(cfg, resolve=True, throw_on_missing=True)
    found = targets(plain)
    assert found, "no _target_ found: the walk is broken"
    for key, target in found:
        assert get_object(target) is not None, f"{key}._target_={target}"
    return plain


@pytest.mark.parametrize("overrides", group_options(), ids=lambda o: " ".join(o))
def test_every_group_option_composes_resolves_and_imports(overrides):
    cfg = compose_cfg([*overrides, *([] if overrides[0].startswith("preset=") else ["preset=cpu"])],
                      hydra_config=True)
    hydra_node = OmegaConf.to_container(cfg.hydra, resolve=False)
    for key, target in targets(hydra_node):  # sweepers and launchers (resolving `hydra` needs a running Hydra)
        assert get_object(target) is not None, f"hydra.{key}._target_={target}"
    with open_dict(cfg):
        del cfg["hydra"]
    assert_resolves(cfg)
    if not cfg.get("suite"):  # and passes the run's own checks: values, and evaluation keys that conf/train.yaml has
        validate_config(cfg)


# ------------------------------------------------------------------------------ experiments, built for real

@pytest.fixture(scope="module")
def inputs(tmp_path_factory, parts_root, cap_file) -> dict[str, list[str]]:
    """What each experiment needs from the user, made small: a cap mesh, an oriented cloud with its rim,
    a family of four caps, a human-part dataset."""
    root = tmp_path_factory.mktemp("inputs")
    cloud, rim, _ = write_oriented_cloud(spherical_cap(subdivisions=2), root)
    family = root / "family"
    family.mkdir()
    for i, height in enumerate((0.15, 0.2, 0.25, 0.3)):
        spherical_cap(height=height, subdivisions=2).export(family / f"{i:03d}.ply")
    parts = [f"data.root={parts_root}"]
    return {
        "minimal_curve": ["data.curve=circle"],
        "recon_mesh": [f"data.mesh={cap_file}"],
        "recon_points": [f"data.points={cloud}", f"data.curve={rim}"],
        "latent_hands": [f"data.path={family}", "data.num_workers=0"],
        "latent_heads": [f"data.path={family}", "data.num_workers=0"],
        "recon_part": [*parts, "data.category=hands"],
        "recon_baseline": parts,
        **{name: parts for name in PARTS},
    }


def build_experiment(overrides: list[str]):
    cfg = compose_cfg([*overrides, *QUIET_CPU, *TINY_NET])
    assert_resolves(cfg)
    return build(cfg)


@pytest.mark.parametrize("experiment", [e for e in EXPERIMENTS if e not in SUITES])
def test_every_experiment_builds_its_datamodule_and_module(experiment, inputs):
    datamodule, module = build_experiment([f"experiment={experiment}", *inputs.get(experiment, [])])
    cfg = composed(f"experiment={experiment}", "preset=paper")
    assert type(module).__name__ == cfg.model._target_.rsplit(".", 1)[-1]
    assert type(datamodule).__name__ == cfg.data._target_.rsplit(".", 1)[-1]
    assert sum(p.numel() for p in module.parameters()) > 0


@pytest.fixture(scope="module")
def body_parts(tmp_path_factory) -> Path:
    """A body folder's part files as experiment=stitched_body reads them: a small cap for each of the 14 parts."""
    from deepcurrents.data.body_partition import BODY_PARTS

    folder = tmp_path_factory.mktemp("body")
    (folder / "parts").mkdir()
    for part in BODY_PARTS:
        spherical_cap(height=0.2, subdivisions=2).export(folder / "parts" / f"{part.name}.ply")
    return folder


@pytest.mark.parametrize("suite", SUITES)
def test_every_suite_member_builds_and_the_report_imports(suite, inputs, body_parts):
    body = [f"suite.body={body_parts}"] if suite == "stitched_body" else []
    cfg = composed(f"experiment={suite}", "preset=paper", *body)
    assert callable(get_object(cfg.suite.report))
    for run in cfg.suite.runs:
        own = member_overrides(run, [], cfg.suite.get("common"))
        experiment = next(o.split("=", 1)[1] for o in own if o.startswith("experiment="))
        # a member's own overrides come last, as run_suite applies them (they name e.g. data.category)
        fills = [o for o in inputs.get(experiment, []) if not o.startswith("data.category=")]
        member = [o for o in own if "wall_time_from" not in o]  # that file exists only in a suite
        build_experiment([*fills, *member])


# -------------------------------------------------------------------------------- lengths and sizes, pinned

COLUMNS = ("trainer.max_steps", "model.optim.step_size", "model.optim.lr", "model.optim.gamma", "data.num_samples",
           "data.num_surface_samples", "model.rff.num_frequencies", "model.net.width", "model.net.depth",
           "callbacks.model_checkpoint.every_n_train_steps", "evaluation.mass_samples", "evaluation.ucd_samples",
           "evaluation.mesh.resolution")
# Composed before configs had one place for lengths (commit 238db52), unchanged since but for one fix:
# recon_baseline under preset=cpu ran 1000 steps (preset_sizes overrode the experiment) where its wall-time
# budget is meant to stop it (1,000,000); and reconstructions, then minimal surfaces, under preset=cpu train at
# lr 3e-3 with a cosine over the budget (preset_sizes/model/cpu_current.yaml, which cpu_reconstruction.yaml includes;
# step_size is then unused); and families under preset=cpu mesh at 80 in a cube of padding 0.5 (was 64 and 0.1:
# σ = 4 shapes bulge out of the smaller cube; preset_sizes/data/cpu_family.yaml), except heads, which keep 64
# with the former settings (preset_sizes/data/cpu_family_heads.yaml); and hands under preset=cpu train 3000 steps of
# 256 + 256 points instead of 1500 of 512 + 512 (docs/notes/families.md "Half the points, twice the steps"), heads
# keep the latter.
# recon_part stands for every recon_<part> alias (tested below).
# Columns in the order of COLUMNS; '-': the key is absent.
LENGTHS_TABLE = """
experiment          preset steps   step  lr     gamma samples surface freqs width depth ckpt  mass    ucd    mesh
latent_hands        paper  300000  60000 0.0004 0.5   4000    4000    1024  256   4     10000 1048576 100000 128
latent_hands        cpu    3000    600   0.001  0.5   256     256     256   128   3     500   1048576 20000  80
latent_heads        paper  300000  60000 0.0004 0.5   4000    4000    1024  256   4     10000 1048576 100000 128
latent_heads        cpu    1500    600   0.001  0.5   512     512     256   128   3     500   1048576 20000  64
minimal_2d          paper  20000   2000  0.0005 0.6   4096    -       1024  256   4     1000  1048576 100000 128
minimal_2d          cpu    3000    1000  0.003  0.6   2048    -       256   128   3     500   1048576 100000 128
minimal_borromean   paper  100000  10000 0.0005 0.6   4096    -       1024  256   4     1000  1048576 100000 128
minimal_borromean   cpu    3000    1000  0.003  0.6   2048    -       256   128   3     500   1048576 100000 128
minimal_curve       paper  100000  10000 0.0005 0.6   4096    -       1024  256   4     1000  1048576 100000 128
minimal_curve       cpu    3000    1000  0.003  0.6   2048    -       256   128   3     500   1048576 100000 128
minimal_grid        paper  5000    10000 0.0005 0.6   1       -       1024  256   4     500   1048576 100000 128
minimal_grid        cpu    2000    1000  0.001  0.6   2048    -       256   128   3     500   1048576 100000 128
minimal_hopf        paper  100000  10000 0.0005 0.6   4096    -       1024  256   4     1000  1048576 100000 128
minimal_hopf        cpu    3000    1000  0.003  0.6   2048    -       256   128   3     500   1048576 100000 128
minimal_trefoil     paper  100000  10000 0.0005 0.6   4096    -       1024  256   4     1000  1048576 100000 128
minimal_trefoil     cpu    3000    1000  0.003  0.6   2048    -       256   128   3     500   1048576 100000 128
recon_2d_semicircle paper  20000   2000  0.0005 0.6   4096    -       1024  256   4     1000  1048576 100000 128
recon_2d_semicircle cpu    400     150   0.003  0.6   1024    -       256   128   3     500   65536   100000 128
recon_baseline      paper  1000000 2000  0.001  0.6   4000    4000    1024  256   4     1000  1048576 100000 128
recon_baseline      cpu    1000000 400   0.001  0.6   1024    1024    256   128   3     500   65536   100000 96
recon_mesh          paper  10000   2000  0.001  0.6   4000    4000    1024  256   4     1000  1048576 100000 128
recon_mesh          cpu    1000    400   0.003  0.6   1024    1024    256   128   3     500   65536   100000 96
recon_points        paper  10000   2000  0.001  0.6   4000    4000    1024  256   4     1000  1048576 100000 128
recon_points        cpu    1000    400   0.003  0.6   1024    1024    256   128   3     500   65536   100000 96
recon_part          paper  10000   2000  0.001  0.6   4000    4000    1024  256   4     1000  1048576 100000 128
recon_part          cpu    1000    400   0.003  0.6   1024    1024    256   128   3     500   65536   100000 96
"""


def parse_lengths(text: str) -> dict[tuple[str, str], tuple]:
    rows = [line.split() for line in text.strip().splitlines()]
    assert len(rows[0]) == 2 + len(COLUMNS)
    return {(r[0], r[1]): tuple(None if c == "-" else yaml.safe_load(c) for c in r[2:]) for r in rows[1:]}


LENGTHS = parse_lengths(LENGTHS_TABLE)


@pytest.mark.parametrize("experiment, preset", sorted(LENGTHS), ids=lambda v: str(v))
def test_lengths_and_sizes_of_every_experiment_are_pinned(experiment, preset):
    cfg = composed(f"experiment={experiment}", f"preset={preset}")
    got = tuple(OmegaConf.select(cfg, key) for key in COLUMNS)
    assert dict(zip(COLUMNS, got, strict=True)) == dict(zip(COLUMNS, LENGTHS[experiment, preset], strict=True))


BUDGET_SCHEDULE = ("model.optim.schedule=cosine", "model.optim.warmup=0.05", "model.optim.min_factor=0.01",
                   "model.optim.fused=true")


@pytest.mark.parametrize("experiment", [e for e in EXPERIMENTS if e not in SUITES])
def test_every_trained_model_takes_the_budget_schedule_without_a_plus(experiment):
    """README, Recipes: the learning rate can follow the budget in every run, families included; a key missing
    from a model's optim node would need Hydra's `+` there and be refused (the grid's ADMM ignores it)."""
    optim = compose_cfg([f"experiment={experiment}", "preset=paper", *BUDGET_SCHEDULE]).model.optim
    assert (optim.schedule, optim.warmup, optim.min_factor, optim.fused) == ("cosine", 0.05, 0.01, True)


def test_every_preset_sizes_file_is_chosen_by_some_experiment():
    chosen = {(group, composed(f"experiment={e}", f"preset={p}").hydra.runtime.choices.get(f"preset_sizes/{group}"))
              for e in EXPERIMENTS if e not in SUITES for p in ("paper", "cpu") for group in ("data", "model")}
    files = {(path.parent.name, path.stem) for path in (CONF / "preset_sizes").glob("*/*.yaml")}
    assert len(files) >= 11 and files <= chosen, f"never chosen (a misspelt data or model name?): {files - chosen}"


def test_the_table_covers_every_experiment():
    runs = {e for e in EXPERIMENTS if e not in SUITES and e not in PARTS}
    assert {e for e, _ in LENGTHS} == runs


@pytest.mark.parametrize("preset", ["paper", "cpu"])
def test_the_command_line_has_the_last_word_over_preset_sizes(preset):
    cfg = compose_cfg(["experiment=recon_hand", f"preset={preset}", "trainer.max_steps=7",
                       "model.optim.step_size=3", "evaluation.mesh.resolution=40", "ablation=no_rff"])
    assert (cfg.trainer.max_steps, cfg.model.optim.step_size, cfg.evaluation.mesh.resolution) == (7, 3, 40)
    assert cfg.model.rff.enabled is False


# ---------------------------------------------------------------------------- one evaluation node, recon_part

@pytest.mark.parametrize("experiment", [e for e in EXPERIMENTS if e not in SUITES])
@pytest.mark.parametrize("preset", ["paper", "cpu"])
def test_models_read_the_one_evaluation_node(experiment, preset):
    cfg = composed(f"experiment={experiment}", f"preset={preset}")
    # the model's node is the root node itself (so an override of evaluation.* reaches the module) ...
    assert OmegaConf.to_container(cfg.model, resolve=False)["evaluation"] == "${evaluation}"
    # ... and no preset or experiment wrote values beside it
    assert OmegaConf.to_container(cfg.model.evaluation, resolve=True) == OmegaConf.to_container(
        cfg.evaluation, resolve=True)


def test_an_evaluation_override_reaches_the_module():
    cfg = compose_cfg(["experiment=latent_hands", "preset=cpu", "evaluation.ucd_samples=123"])
    assert cfg.model.evaluation.ucd_samples == 123 and cfg.model.evaluation.mesh.resolution == 80


def test_no_model_config_states_evaluation_values():
    for path in sorted((CONF / "model").glob("*.yaml")):
        node = OmegaConf.load(path)
        assert OmegaConf.to_container(node, resolve=False).get("evaluation", "${evaluation}") == "${evaluation}", path


@pytest.mark.parametrize("alias, category", sorted(PARTS.items()))
@pytest.mark.parametrize("preset", ["paper", "cpu"])
def test_recon_part_aliases_are_recon_part_with_a_category(alias, category, preset):
    old_cfg = composed(f"experiment={alias}", f"preset={preset}")
    new_cfg = composed("experiment=recon_part", f"data.category={category}", f"preset={preset}")
    assert old_cfg.task_name == alias and new_cfg.task_name == f"recon_{category}"
    # the same config but for the name (what the run directory and the logger's run are called after)
    old, new = (OmegaConf.to_container(c, resolve=False) for c in (old_cfg, new_cfg))
    for key in ("task_name", "hydra"):  # hydra: the command line that composed it
        old.pop(key), new.pop(key)
    assert old == new


def test_recon_part_without_a_category_is_one_sentence(tmp_path):
    with pytest.raises(UserInputError, match="data.category") as info:
        train(compose_cfg(["experiment=recon_part", *QUIET_CPU]), out_dir=tmp_path)
    assert "\n" not in str(info.value)


def test_curve_method_is_checked_and_the_semicircle_keeps_the_level_set():
    from deepcurrents.errors import ConfigError

    assert composed("experiment=minimal_2d").evaluation.curve.method == "phase"
    assert composed("experiment=recon_2d_semicircle").evaluation.curve.method == "level_set"
    with pytest.raises(ConfigError, match="evaluation.curve.method='magic' must be one of phase, level_set"):
        validate_config(composed("experiment=minimal_2d", "evaluation.curve.method=magic"))


def test_the_quick_start_is_the_fast_recipe_at_1500_steps():
    """`make run` (README, Two commands) trains the trefoil with preset=cpu and recipe=sharp for RUN_STEPS steps:
    the Makefile's defaults compose into the sharpened current with importance samples and the mesh-refined mass
    estimate, and `RUN_RECIPE=` gives preset=cpu alone."""
    make = (Path(CONF_DIR).parent / "Makefile").read_text()
    defaults = dict(line.split(" ?= ", 1) for line in make.splitlines() if line.startswith(("RUN_RECIPE", "RUN_STEPS")))
    assert defaults == {"RUN_RECIPE": "recipe=sharp", "RUN_STEPS": "1500"}
    run = [line for line in make.splitlines() if "train.py" in line and "$(RUN_RECIPE)" in line]
    assert len(run) == 1 and "experiment=minimal_trefoil preset=cpu" in run[0]
    cfg = compose_cfg(["experiment=minimal_trefoil", "preset=cpu", defaults["RUN_RECIPE"],
                       f"trainer.max_steps={defaults['RUN_STEPS']}"])
    assert cfg.model.net.phase_sharpening == 2.0 and cfg.model.net.phase_sharpening_start == 0.85
    assert cfg.data.sampling.kind == "importance" and cfg.evaluation.mass_refine_mesh is True
    plain = compose_cfg(["experiment=minimal_trefoil", "preset=cpu"])
    assert plain.model.net.phase_sharpening == 0 and plain.data.sampling.kind == "uniform"


def test_a_schedule_setting_the_runs_schedule_does_not_read_is_warned_about(caplog):
    """preset=cpu's cosine schedule ignores gamma and step_size, preset=paper's step schedule warmup and min_factor:
    the W&B sweep searched gamma under preset=cpu, and minimal_optuna min_factor under preset=paper, without a
    word."""
    import logging

    from deepcurrents.experiments.config import warn_unread_schedule_settings

    settings = ["model.optim.gamma=0.4", "model.optim.min_factor=0.1", "model.optim.lr=1e-3"]
    for preset, unread, read in (("cpu", "gamma=0.4", "min_factor=0.1"), ("paper", "min_factor=0.1", "gamma=0.4")):
        caplog.clear()
        with caplog.at_level(logging.WARNING):
            warn_unread_schedule_settings(composed("experiment=minimal_trefoil", f"preset={preset}"), settings)
        assert f"model.optim.{unread} changes nothing" in caplog.text and read not in caplog.text
        assert "lr=" not in caplog.text
