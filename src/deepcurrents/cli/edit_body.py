"""Boundaries as handles on a stitched body (``experiment=stitched_body``): move one shared loop and refit the parts
it deforms from their checkpoints, so that the edited body is again one closed mesh::

    python -m deepcurrents.cli.edit_body run=outputs/stitched_body/… loop=elbow.L rotate=30     # bend the left arm
    python -m deepcurrents.cli.edit_body run=… loop=wrist.R scale=0.8 carry=false                 # a thinner wrist
    python -m deepcurrents.cli.edit_body run=… loop=neck translate=[0,0.02,0]                     # the head forward

The move is a similarity about the loop's centroid (``data.body_edit``): ``rotate`` degrees about ``axis`` (default
the loop's longest in-plane direction: the hinge of an elbow or a knee), then ``scale``, then ``translate``.
``carry=true`` moves the parts beyond the loop with it (rigidly: their fitted currents map exactly) and refits the
part before it; ``carry=false`` moves the loop alone and refits both parts it joins. Refits run ``steps`` steps from
the parts' checkpoints (``init_from``), side by side. Writes ``body.ply``, ``body.png``, ``edit.png`` (before and
after), ``stitched.json`` and the edited body folder ``body/`` into ``out_dir`` (default ``<run>/edit_<loop>``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import hydra
from omegaconf import MISSING, DictConfig, OmegaConf

from deepcurrents.cli.common import register_app, run_app
from deepcurrents.errors import ConfigError


@dataclass
class EditBodyConfig:
    """``python -m deepcurrents.cli.edit_body`` settings."""

    run: str = MISSING  # a stitched body's folder (experiment=stitched_body)
    loop: str = MISSING  # the shared loop to move (neck, shoulder.L, elbow.L, wrist.L, hip.L, knee.L, ankle.L, … .R)
    rotate: float = 0.0  # degrees about axis, through the loop's centroid
    axis: Any = None  # [x, y, z]; null: the loop's longest in-plane direction
    scale: float = 1.0  # about the loop's centroid
    translate: list = field(default_factory=lambda: [0.0, 0.0, 0.0])
    carry: bool = True  # the parts beyond the loop move with it (true), or only the loop moves (false)
    steps: int = 300  # refit steps of each deformed part, from its checkpoint
    jobs: Any = "auto"  # refits side by side: an integer or auto
    out_dir: str | None = None


register_app("edit_body", EditBodyConfig, __doc__)


def edit(cfg: DictConfig) -> dict[str, Any]:
    from deepcurrents.data.body_edit import LoopMove
    from deepcurrents.experiments.stitched import edit_body

    translate = OmegaConf.to_container(cfg.translate) if OmegaConf.is_list(cfg.translate) else cfg.translate
    if not (isinstance(translate, list) and len(translate) == 3):
        raise ConfigError(f"translate={translate} must be three numbers [x, y, z].")
    if not int(cfg.steps) > 0:
        raise ConfigError(f"steps={cfg.steps} must be a positive number of refit steps.")
    axis = OmegaConf.to_container(cfg.axis) if OmegaConf.is_list(cfg.axis) else cfg.axis
    move = LoopMove(float(cfg.rotate), axis, float(cfg.scale), tuple(float(t) for t in translate))
    out_dir = Path(cfg.out_dir) if cfg.out_dir else Path(cfg.run) / f"edit_{cfg.loop}"
    metrics = edit_body(cfg.run, str(cfg.loop), move, out_dir, bool(cfg.carry), int(cfg.steps), cfg.jobs)
    print(f"wrote body.ply, body.png, edit.png and stitched.json to {out_dir}: {metrics['surface']}, "
          f"{metrics['border_edges']} border edges, UCD {metrics['ucd']:.4g}; refitted {', '.join(metrics['refit'])} "
          f"in {metrics['refit_seconds']} s")
    return metrics


@hydra.main(version_base="1.3", config_path=None, config_name="edit_body")
def main(cfg: DictConfig) -> None:
    run_app(edit, cfg)


if __name__ == "__main__":
    main()
