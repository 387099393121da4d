"""Train a DeepCurrents model: ``python train.py experiment=minimal_trefoil [overrides]``."""

import hydra
from omegaconf import DictConfig

from deepcurrents.train import run_cli


@hydra.main(version_base="1.3", config_path="conf", config_name="train")
def main(cfg: DictConfig) -> float | None:
    return run_cli(cfg)


if __name__ == "__main__":
    main()
