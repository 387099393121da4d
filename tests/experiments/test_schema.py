"""The settings' schema (experiments.schema): every key of every conf/ file is known to it, each kind of bad value
is the user's one sentence, and docs/settings.md is the schema's own reference."""

from __future__ import annotations

import itertools
from pathlib import Path

import pytest
from conftest import CONF_DIR, compose_cfg, hydra_context
from hydra import compose
from omegaconf import OmegaConf

from deepcurrents.errors import ConfigError
from deepcurrents.experiments import schema
from deepcurrents.experiments.config import validate_config

ROOT = Path(__file__).resolve().parents[2]
EXPERIMENTS = sorted(p.stem for p in (Path(CONF_DIR) / "experiment").glob("*.yaml"))
RECIPES = [None, *sorted(p.stem for p in (Path(CONF_DIR) / "recipe").glob("*.yaml"))]
ABLATIONS = sorted(p.stem for p in (Path(CONF_DIR) / "ablation").glob("*.yaml"))


def unknown_leaves(node, cls, path: str) -> list[str]:
    """Dotted keys of ``node`` that the group ``cls`` does not name (nested groups followed)."""
    fields = {f.name: f for f in schema.settings(cls)}
    missing = []
    for key in node:
        name = f"{path}.{key}" if path else str(key)
        if str(key).startswith("_"):
            continue
        if key not in fields:
            missing.append(name)
        elif "group" in fields[key].metadata and OmegaConf.is_dict(node[key]):
            missing += unknown_leaves(node[key], fields[key].metadata["group"], name)
    return missing


def schema_gaps(cfg) -> list[str]:
    gaps = unknown_leaves(cfg.evaluation, schema.Evaluation, "evaluation")
    gaps += unknown_leaves(cfg.trainer, schema.Trainer, "trainer")
    gaps += unknown_leaves(cfg.callbacks, schema.Callbacks, "callbacks")
    for group, kinds in (("data", schema.DATA_KINDS), ("model", schema.MODEL_KINDS)):
        target = str(cfg[group]._target_)
        assert target in kinds, f"{group}._target_={target} has no schema"
        gaps += unknown_leaves(cfg[group], kinds[target], group)
    root = {f.name for f in schema.settings(schema.Root)}
    gaps += [str(k) for k in cfg if not OmegaConf.is_dict(cfg[k]) and k not in root]
    return gaps


# the rules between settings that refuse a combination of conf/ files (the run would fail when built)
REFUSED_COMBINATIONS = ("does not apply to the grid method", "needs a 3D boundary")


@pytest.mark.slow
def test_every_experiment_preset_and_recipe_is_known_to_the_schema_and_valid():
    """Every key is known and every value valid; a refusal is one of the rules between settings."""
    combos = [[f"preset={p}", *([f"experiment={e}"] if e else []), *([f"recipe={r}"] if r else [])]
              for e, p, r in itertools.product([None, *EXPERIMENTS], ["paper", "cpu"], RECIPES)]
    combos += [["experiment=recon_hand", f"ablation={a}"] for a in ABLATIONS]
    with hydra_context():
        for overrides in combos:
            cfg = compose(config_name="train", overrides=overrides)
            assert schema_gaps(cfg) == [], overrides
            try:
                validate_config(cfg)
            except ConfigError as err:
                assert any(words in str(err) for words in REFUSED_COMBINATIONS), (overrides, str(err))


@pytest.mark.parametrize("overrides", [["model=grid", "preset=cpu"], ["model=closest_point", "data=recon_target"],
                                       ["model=autodecoder", "data=family"], ["data=points_2d"],
                                       ["model=reconstruction", "data=recon_curve_2d", "preset=cpu"]])
def test_each_model_and_data_kind_is_known_to_the_schema(overrides):
    cfg = compose_cfg(overrides)
    assert schema_gaps(cfg) == []
    validate_config(cfg)


@pytest.mark.parametrize("override, sentence", [
    # an integer setting: a float, a boolean, below its minimum
    ("data.num_samples=2.5", "data.num_samples=2.5 must be a positive integer."),
    ("trainer.log_every_n_steps=true", "trainer.log_every_n_steps=True must be a positive integer."),
    ("evaluation.mesh.resolution=4", "evaluation.mesh.resolution=4 must be an integer ≥ 8."),
    ("evaluation.sharpened.samples=-1", "evaluation.sharpened.samples=-1 must be an integer ≥ 0."),
    # a number: negative, a word, out of its interval
    ("evaluation.mesh.delta=-1", "evaluation.mesh.delta=-1 must be a non-negative number."),
    ("evaluation.mesh.min_alignment=2", "evaluation.mesh.min_alignment=2 must be in [-1, 1]."),
    ("evaluation.mesh.padding=1.5", "evaluation.mesh.padding=1.5 must be in [0, 1]."),
    ("model.optim.lr=fast", "model.optim.lr=fast must be a positive number."),
    ("model.optim.gamma=1.5", "model.optim.gamma=1.5 must be in (0, 1]."),
    ("model.rff.sigma=0", "model.rff.sigma=0 must be positive."),
    ("model.rff.coarse_to_fine=2", "model.rff.coarse_to_fine=2.0 must be a fraction of the budget in [0, 1] "
                                   "(0: every frequency from the start)."),
    ("model.optim.warmup=1", "model.optim.warmup=1.0 must be a fraction of the budget in [0, 1)."),
    # a choice, a boolean
    ("evaluation.mesh.method=magic", "evaluation.mesh.method='magic' must be one of"),
    ("model.optim.schedule=linear", "model.optim.schedule='linear' must be one of step, cosine."),
    ("model.optim.fused=yes", "model.optim.fused='yes' must be true or false."),
    ("evaluation.mass_refine_mesh=yes", "evaluation.mass_refine_mesh='yes' must be true or false."),
    # an unknown key of a fixed group
    ("+evaluation.mesh.resolutoin=64", "evaluation.mesh.resolutoin is not a setting of evaluation.mesh"),
    ("+model.optim.lrr=1", "model.optim.lrr is not a setting of model.optim (its settings: lr, step_size"),
    ("+model.rff.sigmaa=1", "model.rff has unknown keys ['sigmaa']; it takes coarse_start"),
    # the root and the trainer
    ("torch_threads=0", "torch_threads=0 must be a positive integer, auto"),
    ("trainer.max_time=3min", "trainer.max_time='3min' must be a number of seconds or DD:HH:MM:SS"),
    ("trainer.max_steps=-1", "trainer.max_steps=-1 (no step limit) needs a time budget"),
    ("trainer.precision=16-mixed", "trainer.precision=16-mixed is not supported"),
    # settings that constructors also check, in their words
    ("model.net.activation=tanh", "model.net.activation='tanh' must be one of relu, softplus."),
    ("model.net.phase_sharpening=-1", "model.net.phase_sharpening=-1 must be a concentration κ ≥ 0 (0: off)."),
    ("model.net.phase_harmonics_start=1", "model.net.phase_harmonics_start=1 must be a fraction of the training"),
    ("data.curve_vertices=2", "data.curve_vertices=2 must be an integer ≥ 3."),
    ("data.normalize=maybe", "data.normalize='maybe' must be true, false or auto."),
    ("data.sampling.kind=random", "data.sampling.kind='random' must be one of uniform, sobol, importance."),
    ("data.sampling.uniform_fraction=0", "data.sampling.uniform_fraction=0 must be in (0, 1] (a uniform share"),
])
def test_a_bad_value_is_the_users_one_sentence(override, sentence):
    with pytest.raises(ConfigError) as err:
        validate_config(compose_cfg([override]))
    assert str(err.value).startswith(sentence), str(err.value)


@pytest.mark.parametrize("overrides, sentence", [
    (["experiment=latent_hands", "model.net.f_turns=0.5"], "model.net.f_turns=0.5 must be 0 (no window) or above 1"),
    (["experiment=latent_hands", "model.winding_reach=0.5"], "model.winding_reach=0.5 must be a finite number ≥ 1."),
    (["experiment=latent_hands", "model.interpolation_mix=both"], "model.interpolation_mix='both' must be one of"),
    (["experiment=latent_hands", "model.latent_fit.steps=0"], "model.latent_fit.steps=0 must be a positive integer."),
    (["experiment=recon_hand", "model.surface_margin=0"], "model.surface_margin=0 must be positive."),
    (["experiment=recon_hand", "+data.batch_kind=other"], "data.batch_kind='other' must be 'current' or"),
    (["model=grid", "model.admm.relaxation=2"], "model.admm.relaxation=2 must be in [1, 2)."),
    (["model=grid", "model.grid.resolution=2"], "model.grid.resolution=2 must be an integer ≥ 4."),
])
def test_a_bad_value_of_a_model_or_data_kind_is_its_constructors_sentence(overrides, sentence):
    with pytest.raises(ConfigError) as err:
        validate_config(compose_cfg(overrides))
    assert str(err.value).startswith(sentence), str(err.value)


def test_the_rules_between_settings_name_both():
    with pytest.raises(ConfigError, match="does not apply to the grid method"):
        validate_config(compose_cfg(["model=grid", "trainer.gradient_clip_val=0.1"]))
    with pytest.raises(ConfigError, match="model.mass_weight needs uniform ambient samples"):
        validate_config(compose_cfg(["experiment=recon_hand", "model.mass_weight=0.1", "data.sampling.kind=near"]))
    with pytest.raises(ConfigError, match="model.net.phase_harmonics=8 needs a 3D boundary"):
        validate_config(compose_cfg(["experiment=minimal_2d", "recipe=harmonics"]))
    with pytest.raises(ConfigError, match="model.grid.dtype='float16' must be one of"):
        validate_config(compose_cfg(["model=grid", "model.grid.dtype=float16"]))


def test_every_setting_has_a_meaning():
    groups = [schema.Root, schema.Trainer, schema.Callbacks, schema.Evaluation,
              *schema.DATA_KINDS.values(), *schema.MODEL_KINDS.values()]
    for cls in groups:
        for key, _, _, _, meaning in schema._rows(cls, ""):
            assert meaning and "\n" not in meaning, (cls.__name__, key)


def test_the_settings_reference_is_up_to_date():
    assert (ROOT / "docs" / "settings.md").read_text() == schema.reference(), \
        "docs/settings.md is stale: python -m deepcurrents.experiments.schema > docs/settings.md"
