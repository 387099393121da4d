"""Training entry point: config → DataModule → LightningModule → Trainer → final evaluation.

The project's ``train.py`` is a thin Hydra wrapper around :func:`train`.
"""

from __future__ import annotations

import json
import logging
import sys
from pathlib import Path
from typing import Any

import hydra
import lightning as L
from hydra.core.hydra_config import HydraConfig
from hydra.errors import InstantiationException
from omegaconf import DictConfig, OmegaConf

from deepcurrents.checkpointing import AtomicCheckpointIO
from deepcurrents.config import validate_config
from deepcurrents.errors import NonFiniteLossError, UserInputError
from deepcurrents.models.current_module import boundary_spec

log = logging.getLogger("deepcurrents")


def instantiate(node: DictConfig, **kwargs):
    """hydra.utils.instantiate, but a UserInputError raised inside a constructor comes out as itself
    (Hydra wraps it in an InstantiationException with the target's traceback text)."""
    try:
        return hydra.utils.instantiate(node, **kwargs)
    except InstantiationException as err:
        cause = err.__cause__
        while cause is not None and not isinstance(cause, UserInputError):
            cause = cause.__cause__
        if cause is not None:
            raise cause from None
        raise


def output_dir(cfg: DictConfig) -> Path:
    """The run directory: Hydra's when running under Hydra, else ``cfg.paths.output_dir``."""
    if HydraConfig.initialized():
        return Path(HydraConfig.get().runtime.output_dir)
    return Path(cfg.paths.output_dir)


def build_logger(cfg: DictConfig, out_dir: Path):
    if cfg.get("logger") is None:
        return False
    kwargs = {}
    if "save_dir" in cfg.logger:
        kwargs["save_dir"] = str(out_dir)
    return instantiate(cfg.logger, **kwargs)


def build_callbacks(cfg: DictConfig, out_dir: Path) -> list:
    callbacks = []
    for name, cb in (cfg.get("callbacks") or {}).items():
        if cb is None:
            continue
        kwargs = {"dirpath": str(out_dir / "checkpoints")} if name == "model_checkpoint" else {}
        callbacks.append(instantiate(cb, **kwargs))
    return callbacks


def build(cfg: DictConfig):
    """The DataModule and the LightningModule of a run (validates the inputs; trains nothing)."""
    datamodule = instantiate(cfg.data, _convert_="all")
    spec = boundary_spec(datamodule.boundary) if hasattr(datamodule, "boundary") else None
    kwargs = {"boundary": spec} if spec is not None else {}
    extra = getattr(datamodule, "model_kwargs", None)
    if callable(extra):
        kwargs.update(extra())
    module = instantiate(cfg.model, _convert_="all", **kwargs)
    module.run_config = OmegaConf.to_container(cfg, resolve=True)
    return datamodule, module


def train(cfg: DictConfig, out_dir: Path | None = None) -> dict[str, Any] | None:
    """Trains and evaluates one run into ``out_dir`` (default: the run directory); returns its metrics
    (None on non-zero DDP ranks). A config with a ``suite`` runs each member instead (deepcurrents.suites).
    """
    out_dir = Path(out_dir) if out_dir is not None else output_dir(cfg)
    out_dir.mkdir(parents=True, exist_ok=True)
    if cfg.get("suite"):
        from deepcurrents.suites import run_suite

        run_suite(cfg, out_dir)
        return None
    validate_config(cfg)
    L.seed_everything(int(cfg.seed), workers=True, verbose=False)
    datamodule, module = build(cfg)
    trainer: L.Trainer = instantiate(
        cfg.trainer,
        logger=build_logger(cfg, out_dir),
        callbacks=build_callbacks(cfg, out_dir),
        plugins=[AtomicCheckpointIO()],
        default_root_dir=str(out_dir),
    )
    ckpt_path = cfg.get("ckpt_path")
    if ckpt_path is not None and not Path(ckpt_path).is_file():
        raise UserInputError(f"ckpt_path='{ckpt_path}' does not exist or is not a file.")
    trainer.fit(module, datamodule=datamodule, ckpt_path=ckpt_path)
    # the final state, whatever step it ended on (periodic checkpoints may be older)
    trainer.save_checkpoint(out_dir / "checkpoints" / "last.ckpt")
    if trainer.interrupted:
        log.warning("Training was interrupted; evaluating the model as it is.")
    if not trainer.is_global_zero:
        return None
    metrics = module.final_evaluation(out_dir)
    log.info("metrics: %s", json.dumps(metrics))
    for cb in trainer.callbacks:  # final media (deepcurrents.callbacks.MediaCallback) before loggers close
        hook = getattr(cb, "on_final_evaluation", None)
        if callable(hook):
            hook(trainer, module, metrics, out_dir)
    for lg in trainer.loggers:
        lg.log_metrics({f"final/{k}": v for k, v in metrics.items() if isinstance(v, (int, float))},
                       step=int(module.global_step))
        if hasattr(lg, "experiment") and hasattr(lg.experiment, "summary"):
            lg.experiment.summary.update({f"final/{k}": v for k, v in metrics.items()})
        lg.finalize("success")
    return metrics


def run_cli(cfg: DictConfig) -> float | None:
    """Runs :func:`train`, turning user errors into one sentence and a non-zero exit (no traceback).

    Returns the value an Optuna sweep minimises (``cfg.objective``), if set.
    """
    try:
        metrics = train(cfg)
    except UserInputError as err:
        print(f"error: {err}", file=sys.stderr)
        sys.exit(2)
    except NonFiniteLossError as err:
        print(f"error: {err}", file=sys.stderr)
        sys.exit(3)
    objective = cfg.get("objective")
    if metrics is not None and objective:
        value = metrics.get(objective)
        return float(value) if value is not None else float("inf")
    return None
