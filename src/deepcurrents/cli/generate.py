"""A surface for a new (edited) boundary from a family model (paper §5.3: the boundary is the handle)::

    python -m deepcurrents.cli.generate ckpt_path=…/last.ckpt curve=edited_rim.obj latent=3

``curve`` is a curve file (``.obj`` polylines, one ``l`` per loop; ``.txt``/``.npy`` for one loop; or a
named curve such as ``circle``) with as many loops as the family's shapes have. Its loops are matched to
those of training shape ``latent`` by their centroids (the order in the file does not matter), and a loop
that turns against its match is reversed (with a warning), so that the current points the way the
family's surfaces do.

Writes ``<name>.ply`` (the surface, its border on the new Γ), ``<name>_boundary.obj`` (Γ as used),
``<name>.png`` and ``<name>.json`` (boundary_error, area, ...) into ``out_dir`` (default:
``<run>/checkpoints/last/generated`` beside the checkpoint), ``name`` defaulting to ``<curve stem>_latent<k>``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import hydra
from omegaconf import MISSING, DictConfig

from deepcurrents.cli.common import plain_file_name, register_app, run_app
from deepcurrents.cli.families import app_out_dir, load_for_app, mesh_and_measure, write_outputs
from deepcurrents.errors import ConfigError
from deepcurrents.geometry.correspondence import align_loops
from deepcurrents.geometry.curves import load_boundary

log = logging.getLogger("deepcurrents")


@dataclass
class GenerateConfig:
    """``python -m deepcurrents.cli.generate`` settings."""

    ckpt_path: str = MISSING  # a family checkpoint (…/checkpoints/last.ckpt)
    curve: str = MISSING  # the new boundary: a curve file (or a named curve: circle, trefoil, hopf, …)
    latent: int = 0  # the training shape whose latent code is used
    curve_scale: float = 1.0  # multiplies the curve's coordinates
    name: str | None = None  # output file stem (default <curve stem>_latent<k>)
    out_dir: str | None = None
    resolution: int | None = None
    padding: float | None = None  # the meshed cube's margin, in [0, 1] (default: the run's evaluation.mesh.padding)
    device: str = "auto"


register_app("generate", GenerateConfig, __doc__)


def generate(cfg: DictConfig) -> dict[str, Any]:
    """Meshes the family member (z_latent, Γ from the curve file). → the report written to <name>.json."""
    if not float(cfg.curve_scale) > 0:
        raise ConfigError(f"curve_scale={cfg.curve_scale} must be positive.")
    given = plain_file_name(cfg.name)
    module = load_for_app(cfg)
    k = module.check_shape_index(cfg.latent, "latent")
    source = f"curve='{cfg.curve}'"
    boundary = load_boundary(str(cfg.curve), scale=float(cfg.curve_scale), setting="curve")
    loops = align_loops(boundary.loops, module.shape_loops(k), source)
    name = given or f"{Path(str(cfg.curve)).stem}_latent{k}"
    out_dir = app_out_dir(cfg, "generated")
    rec = mesh_and_measure(module, module.latent(k), loops, [k], out_dir, name)
    rec["title"] = f"boundary error {rec['boundary_error']:.2g}" if rec["boundary_error"] is not None \
        else "empty mesh"
    info = {"curve": str(cfg.curve), "latent": k, "latent_name": list(module.hparams.shape_names)[k],
            "ckpt_path": str(cfg.ckpt_path)}
    report = write_outputs(out_dir, [rec], info, 1, f"{name}.png", f"{name}.json")
    print(f"wrote {name}.ply, {name}.png and {name}.json to {out_dir} (boundary_error {rec['boundary_error']})")
    return report


@hydra.main(version_base="1.3", config_path=None, config_name="generate")
def main(cfg: DictConfig) -> None:
    run_app(generate, cfg)


if __name__ == "__main__":
    main()
