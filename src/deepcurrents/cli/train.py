"""``python train.py experiment=NAME [overrides]`` (also ``deepcurrents-train``): trains and evaluates one
run (or a suite of runs) into Hydra's run directory; user errors end in one sentence and a non-zero exit."""

from __future__ import annotations

from pathlib import Path

import hydra
from omegaconf import DictConfig

from deepcurrents.cli.common import exit_on_user_error
from deepcurrents.experiments.runner import train

CONFIG_DIR = str(Path(__file__).resolve().parents[3] / "conf")


def run_cli(cfg: DictConfig) -> float | None:
    """Runs :func:`train`, turning user errors into one sentence and a non-zero exit (no traceback).

    Returns the value an Optuna sweep minimises (``cfg.objective``), if set.
    """
    metrics = exit_on_user_error(train, cfg)
    objective = cfg.get("objective")
    if metrics is not None and objective:
        value = metrics.get(objective)
        return float(value) if value is not None else float("inf")
    return None


@hydra.main(version_base="1.3", config_path=CONFIG_DIR, config_name="train")
def main(cfg: DictConfig) -> float | None:
    return run_cli(cfg)


if __name__ == "__main__":
    main()
