"""The run's logger (``cfg.logger``: W&B, CSV or none): one logged run per job, named and grouped by the command that
made it, carrying the run's whole config, and closed when the job ends.

W&B keeps one run per process until ``finish`` is called; Lightning's ``WandbLogger.finalize`` does not call it, so
without :func:`finished_loggers` every job of a multirun, Optuna search or suite after the first logged into the first
job's run (its config and summary overwritten by the last job's, later jobs' final rows dropped as out of order).
"""

from __future__ import annotations

import logging
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import lightning as L
from hydra.core.hydra_config import HydraConfig
from hydra.utils import instantiate
from omegaconf import DictConfig

from deepcurrents.experiments.multirun import in_multirun

log = logging.getLogger(__name__)

WANDB_GROUP_LIMIT = 128  # characters W&B keeps of a group name


def is_wandb(logger_cfg: DictConfig) -> bool:
    return str(logger_cfg.get("_target_", "")).endswith("WandbLogger")


def build_logger(cfg: DictConfig, out_dir: Path, member: str | None = None):
    """``cfg.logger`` instantiated into ``out_dir`` (False without one). A W&B run is named after the task, then
    the suite member (``member``) or the multirun job's number, and grouped by the suite's run directory or the
    sweep's directory, so that the runs of one command sit together; ``logger.group`` set by the user wins."""
    if cfg.get("logger") is None:
        return False
    kwargs: dict[str, Any] = {}
    if "save_dir" in cfg.logger:
        kwargs["save_dir"] = str(out_dir)
    if is_wandb(cfg.logger):
        name = str(cfg.logger.get("name") or cfg.get("task_name") or "run")
        group = None
        if member is not None:
            name, group = f"{name}/{member}", str(out_dir.parent)
        elif in_multirun():
            name, group = f"{name}/{HydraConfig.get().job.num}", str(HydraConfig.get().sweep.dir)
        kwargs["name"] = name
        if group is not None and not cfg.logger.get("group"):
            kwargs["group"] = group[-WANDB_GROUP_LIMIT:]
    return instantiate(cfg.logger, **kwargs)


class LogRunConfig(L.Callback):
    """Hands every logger the run's config (the module's ``run_config`` with the overrides) when fitting starts,
    in place of Lightning's own record of the module's init arguments (``enable_autolog_hparams=False``), which
    lacked the data, trainer and seed settings and carried every vertex of Γ."""

    def __init__(self, config: dict[str, Any]) -> None:
        self.config = config

    def on_fit_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        for lg in trainer.loggers:  # rank zero only (the loggers' own guard)
            lg.log_hyperparams(self.config)


@contextmanager
def finished_loggers(trainer: L.Trainer):
    """Closes the job's W&B run when the block ends (status failed when it raised), so that the next job of a
    multirun, Optuna search or suite starts a run of its own; other loggers need nothing."""
    failed = True
    try:
        yield
        failed = False
    finally:
        for lg in trainer.loggers:
            experiment = getattr(lg, "_experiment", None)  # W&B's run, made on first use: never on other ranks
            if experiment is not None and callable(getattr(experiment, "finish", None)):
                try:
                    experiment.finish(exit_code=1 if failed else 0)
                except Exception as err:  # closing the log must not hide the job's own outcome
                    log.warning("Closing the W&B run failed: %s", err)
