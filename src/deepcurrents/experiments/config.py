"""Checks of configuration values that no constructor owns, before anything is built or trained."""

from __future__ import annotations

from omegaconf import DictConfig, OmegaConf

from deepcurrents.errors import ConfigError, positive_int
from deepcurrents.eval.meshing import MESH_METHOD_CHOICES


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


def validate_config(cfg: DictConfig) -> None:
    """Raises ConfigError naming the first impossible value (steps, samples, evaluation sizes)."""
    _positive_int(cfg, "trainer.max_steps")
    _positive_int(cfg, "data.num_samples")
    _positive_int(cfg, "evaluation.mass_samples")
    _positive_int(cfg, "evaluation.mesh.resolution", 8)
    _positive_int(cfg, "evaluation.curve.resolution", 8)
    _positive_int(cfg, "callbacks.model_checkpoint.every_n_train_steps")
    for key in ("evaluation.mesh.delta", "evaluation.mesh.boundary_tube", "evaluation.mesh.padding",
                "evaluation.curve.delta", "evaluation.curve.boundary_tube"):
        _nonnegative(cfg, key)
    method = OmegaConf.select(cfg, "evaluation.mesh.method")
    if method is not None and method not in MESH_METHOD_CHOICES:
        raise ConfigError(f"evaluation.mesh.method={method!r} must be one of {', '.join(MESH_METHOD_CHOICES)}.")
