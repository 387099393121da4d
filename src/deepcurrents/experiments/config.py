"""Checks of configuration values that no constructor owns, before anything is built or trained."""

from __future__ import annotations

import logging
import re
from datetime import timedelta
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from deepcurrents.errors import ConfigError, number_between, positive_int
from deepcurrents.eval.meshing import CURVE_METHODS, MESH_METHOD_CHOICES
from deepcurrents.eval.meshing.curve_2d import check_curve_grid
from deepcurrents.models.schedules import SCHEDULE_KEYS

log = logging.getLogger(__name__)


def _positive_int(cfg: DictConfig, key: str, minimum: int = 1) -> None:
    value = cfg
    for part in key.split("."):
        if value is None or part not in value:
            return
        value = value[part]
    if value is None:
        return
    positive_int(key, value, minimum)


def _nonnegative(cfg: DictConfig, key: str) -> None:
    value = cfg
    for part in key.split("."):
        if value is None or part not in value:
            return
        value = value[part]
    if value is not None and not (isinstance(value, (int, float)) and value >= 0):
        raise ConfigError(f"{key}={value!r} must be a non-negative number.")


def max_time_seconds(value: Any) -> float | None:
    """``trainer.max_time`` in seconds: None (no time limit), a number of seconds, Lightning's "DD:HH:MM:SS"
    string, or a dict of timedelta keywords ({minutes: 3}). Anything else: one sentence naming the key."""
    if value is None:
        return None
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        seconds = float(value)
    elif isinstance(value, str):
        match = re.fullmatch(r"(\d+):(\d\d):(\d\d):(\d\d)", value.strip())
        if match is None:
            raise ConfigError(f"trainer.max_time={value!r} must be a number of seconds or DD:HH:MM:SS "
                              "(e.g. 00:00:03:00 for three minutes).")
        d, h, m, s = (int(g) for g in match.groups())
        seconds = timedelta(days=d, hours=h, minutes=m, seconds=s).total_seconds()
    elif isinstance(value, dict) or OmegaConf.is_dict(value):
        try:
            seconds = timedelta(**{k: float(v) for k, v in dict(value).items()}).total_seconds()
        except (TypeError, ValueError) as err:
            raise ConfigError(f"trainer.max_time={dict(value)!r} is not a duration ({err}).") from None
    else:
        raise ConfigError(f"trainer.max_time={value!r} must be a number of seconds or DD:HH:MM:SS.")
    if not seconds > 0:
        raise ConfigError(f"trainer.max_time={value!r} must be a positive duration.")
    return seconds


def trainer_overrides(cfg: DictConfig) -> dict[str, Any]:
    """Keyword arguments that replace config values when the Trainer is built: ``max_time`` as a
    timedelta (Lightning refuses a plain number of seconds)."""
    seconds = max_time_seconds(OmegaConf.select(cfg, "trainer.max_time"))
    return {"max_time": timedelta(seconds=seconds)} if seconds is not None else {}


CONFIG_DIR = str(Path(__file__).resolve().parents[3] / "conf")  # the repository's Hydra configs


def check_evaluation_keys(node: Any, known: Any, path: str = "evaluation") -> None:
    """ConfigError for a key of the run's ``evaluation`` node that conf/train.yaml's does not have (the one place of
    its settings): they are read by name, so ``+evaluation.mesh.resolutoin=64`` was ignored without a word."""
    for key in node:
        if key not in known:
            raise ConfigError(f"{path}.{key} is not a setting of {path} (its settings: {', '.join(map(str, known))}).")
        if OmegaConf.is_dict(node[key]) and OmegaConf.is_dict(known[key]):
            check_evaluation_keys(node[key], known[key], f"{path}.{key}")


def validate_config(cfg: DictConfig) -> None:
    """Raises ConfigError naming the first impossible value (steps, samples, evaluation sizes)."""
    if OmegaConf.is_dict(cfg.get("evaluation")):
        check_evaluation_keys(cfg.evaluation, OmegaConf.load(Path(CONFIG_DIR) / "train.yaml").evaluation)
    max_steps = OmegaConf.select(cfg, "trainer.max_steps")
    if max_steps != -1:  # Lightning's "no step limit"
        _positive_int(cfg, "trainer.max_steps")
    seconds = max_time_seconds(OmegaConf.select(cfg, "trainer.max_time"))
    if max_steps == -1 and seconds is None:
        raise ConfigError("trainer.max_steps=-1 (no step limit) needs a time budget: set trainer.max_time "
                          "(seconds or DD:HH:MM:SS).")
    precision = OmegaConf.select(cfg, "trainer.precision")
    if precision is not None and str(precision) not in ("32-true", "32"):
        value = str(precision)
        if value in ("64-true", "64"):
            why = "the final evaluation, meshing and rendering build float32 points and grids"
        elif "16" in value:  # 16-mixed, bf16-mixed, 16-true, bf16-true, 16, bf16
            # under autocast α's products would meet float32 operands (a dtype error deep in torch)
            why = ("its training pass and Biot–Savart run in the parameters' precision whatever autocast asks (the "
                   "mass loss is sensitive to rounding), so half precision cannot speed it up; for faster matrix "
                   "products use model.net.matmul_precision=medium (bf16 or TF32 internals in float32 products)")
        else:
            why = "32-true is the only precision it runs in"
        raise ConfigError(f"trainer.precision={precision} is not supported: DeepCurrents trains in float32 "
                          f"(32-true), and {why}.")
    threads = OmegaConf.select(cfg, "torch_threads")
    if threads not in (None, "auto") and (isinstance(threads, bool) or not isinstance(threads, int) or threads < 1):
        raise ConfigError(f"torch_threads={threads!r} must be a positive integer, auto (the cores left beside the "
                          "loader workers) or null (torch's choice).")
    _positive_int(cfg, "data.num_samples")
    _positive_int(cfg, "evaluation.mass_samples")
    _positive_int(cfg, "evaluation.mass_refine")
    _positive_int(cfg, "evaluation.ucd_samples")
    _positive_int(cfg, "evaluation.seed", 0)
    _positive_int(cfg, "evaluation.max_shapes")
    _positive_int(cfg, "evaluation.mesh.newton_steps", 0)
    _positive_int(cfg, "evaluation.mesh.resolution", 8)
    _positive_int(cfg, "evaluation.mesh.strip_rows")
    _positive_int(cfg, "evaluation.sharpened.samples", 0)  # 0: no sharpened bound; 0.5 dropped it silently
    _positive_int(cfg, "evaluation.curve.resolution", 8)
    if OmegaConf.select(cfg, "evaluation.curve.resolution") is not None:  # before the training (any 2D data kind)
        check_curve_grid(cfg.evaluation.curve.resolution, "evaluation.curve.resolution")
    _positive_int(cfg, "callbacks.model_checkpoint.every_n_train_steps")
    _positive_int(cfg, "trainer.log_every_n_steps")  # 0 silently turned the training logs off
    for key in ("evaluation.mass_rel_stderr", "evaluation.mass_tube_radius", "evaluation.mesh.delta",
                "evaluation.mesh.boundary_tube", "evaluation.mesh.padding", "evaluation.mesh.level_blend",
                "evaluation.sharpened.kappa", "evaluation.curve.delta",
                "evaluation.curve.boundary_tube"):
        _nonnegative(cfg, key)
    for key, lo, hi in (("evaluation.mesh.min_alignment", -1.0, 1.0), ("evaluation.curve.min_alignment", -1.0, 1.0),
                        ("evaluation.mesh.min_component", 0.0, 1.0),  # a cosine; a fraction of the area
                        ("evaluation.mesh.padding", 0.0, 1.0)):  # the box's growth, as the apps take it
        if OmegaConf.select(cfg, key) is not None:
            number_between(key, OmegaConf.select(cfg, key), lo, hi)
    for key in ("evaluation.mass_refine_mesh", "evaluation.mesh.close_boundary"):  # 'false' (a string) is truthy
        value = OmegaConf.select(cfg, key)
        if value not in (None, True, False):
            raise ConfigError(f"{key}={value!r} must be true or false.")
    method = OmegaConf.select(cfg, "evaluation.mesh.method")
    if method is not None and method not in MESH_METHOD_CHOICES:
        raise ConfigError(f"evaluation.mesh.method={method!r} must be one of {', '.join(MESH_METHOD_CHOICES)}.")
    curve_method = OmegaConf.select(cfg, "evaluation.curve.method")
    if curve_method is not None and curve_method not in CURVE_METHODS:
        raise ConfigError(f"evaluation.curve.method={curve_method!r} must be one of {', '.join(CURVE_METHODS)}.")
    clip = OmegaConf.select(cfg, "trainer.gradient_clip_val")
    if clip and str(OmegaConf.select(cfg, "model._target_", default="")).endswith(".GridModule"):
        # else Lightning's "remove Trainer(gradient_clip_val=0.1)", a setting the user never typed
        raise ConfigError(f"trainer.gradient_clip_val={clip} (set by recipe=sharp, or on the command line) does "
                          "not apply to the grid method (model=grid): its ADMM takes no gradient steps; drop "
                          "recipe=sharp, or set trainer.gradient_clip_val=null.")
    if (OmegaConf.select(cfg, "model.mass_weight") or 0) > 0 and OmegaConf.select(cfg, "data.sampling.kind") == "near":
        # the near samples' importance weights are folded into the metric, so E|ω| would not be the mass
        raise ConfigError("model.mass_weight needs uniform ambient samples; data.sampling.kind=near weights "
                          "them into the metric only.")


def warn_unread_schedule_settings(cfg: DictConfig, overrides: list[str]) -> None:
    """A warning for each command-line override (a sweep's swept values included) of a ``model.optim`` setting that
    the run's schedule does not read: ``preset=cpu`` uses the cosine schedule, which ignores ``gamma`` and
    ``step_size``, and ``preset=paper`` the step schedule, which ignores ``warmup`` and ``min_factor``; a sweep
    over them searched a dimension that changed nothing, without a word."""
    schedule = OmegaConf.select(cfg, "model.optim.schedule", default=None)
    if schedule not in SCHEDULE_KEYS:
        return
    unread = {f"model.optim.{k}" for other, keys in SCHEDULE_KEYS.items() if other != schedule for k in keys}
    for override in overrides:
        key, _, value = override.lstrip("+~").partition("=")
        if key in unread:
            log.warning("%s=%s changes nothing: this run's schedule, model.optim.schedule=%s (set by its experiment "
                        "and preset), reads %s instead; set those, or choose the other schedule.", key, value,
                        schedule, " and ".join(SCHEDULE_KEYS[schedule]))
