"""The run's configuration before anything is built: its checks (experiments.schema) and the Trainer's overrides."""

from __future__ import annotations

import logging
from datetime import timedelta
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from deepcurrents.experiments.schema import max_time_seconds, validate
from deepcurrents.models.schedules import SCHEDULE_KEYS

__all__ = ["CONFIG_DIR", "max_time_seconds", "trainer_overrides", "validate_config", "warn_unread_schedule_settings"]

log = logging.getLogger(__name__)


def trainer_overrides(cfg: DictConfig) -> dict[str, Any]:
    """Keyword arguments that replace config values when the Trainer is built: ``max_time`` as a
    timedelta (Lightning refuses a plain number of seconds)."""
    seconds = max_time_seconds(OmegaConf.select(cfg, "trainer.max_time"))
    return {"max_time": timedelta(seconds=seconds)} if seconds is not None else {}


CONFIG_DIR = str(Path(__file__).resolve().parents[3] / "conf")  # the repository's Hydra configs


def validate_config(cfg: DictConfig) -> None:
    """Raises ConfigError naming the first impossible value (steps, samples, evaluation sizes): the composed config
    against the schema of each group (experiments.schema), before anything is built."""
    validate(cfg)


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
