"""Interpolate between two training shapes of a family model (paper §5.3, Fig. 6)::

    python -m deepcurrents.cli.interpolate ckpt_path=…/last.ckpt mode=latent a=3 b=12 steps=5
    python -m deepcurrents.cli.interpolate ckpt_path=… mode=boundary a=3 b=12 steps=5
    python -m deepcurrents.cli.interpolate ckpt_path=… mode=grid a=3 b=12 steps=5

- ``latent``: z = (1 − t) z_a + t z_b with the boundary of shape ``hold`` (default a) held fixed;
- ``boundary``: Γ = (1 − t) Γ_a + t Γ_b vertex by vertex (loops are matched across the family at training
  time, see ``geometry.correspondence``), with the latent code of ``hold`` held fixed;
- ``grid``: rows interpolate the latent code, columns the boundary (``steps`` × ``steps``), as Fig. 6.

Writes, into ``out_dir`` (default: ``<run>/checkpoints/last/interpolation_<mode>_<a>_<b>[_hold_b]``, beside the
checkpoint):
one mesh ``.ply`` and its boundary ``.obj`` per interpolant, ``interpolation.png`` (the grid of pictures)
and ``interpolation.json`` with each interpolant's ``boundary_error`` (Hausdorff distance between the
mesh's border and the prescribed Γ: the boundary is the handle, so this is what to watch) and its
``crispness`` = mass_area / mesh_area (≈ 1 for a clean sheet, larger for fog; ``mass_samples=0`` skips it),
``area_fraction`` (its mesh area over the smaller of the two end shapes', each under its own code and boundary) and
``vanished`` (below 1/4: closed on Γ or not, no shape of the family), counted in ``meshes_vanished``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

import hydra
import numpy as np
from omegaconf import MISSING, DictConfig

from deepcurrents.cli.common import register_app, run_app
from deepcurrents.cli.families import app_out_dir, load_for_app, mark_vanished, mesh_and_measure, write_outputs
from deepcurrents.errors import ConfigError, positive_int
from deepcurrents.geometry.correspondence import interpolate_loops

log = logging.getLogger("deepcurrents")

MODES = ("latent", "boundary", "grid")


@dataclass
class InterpolateConfig:
    """``python -m deepcurrents.cli.interpolate`` settings."""

    ckpt_path: str = MISSING  # a family checkpoint (…/checkpoints/last.ckpt)
    mode: str = "latent"  # latent | boundary | grid
    a: int = 0  # training shape indices (rows of the latent table; see per_shape.csv of the run)
    b: int = 1
    steps: int = 5  # interpolants per axis, t = 0 … 1 inclusive
    hold: str = "a"  # which shape's boundary (latent mode) or latent code (boundary mode) is held fixed
    out_dir: str | None = None
    resolution: int | None = None  # marching-cubes resolution (default: the run's evaluation.mesh)
    padding: float | None = None  # the meshed cube's margin, in [0, 1] (default: the run's evaluation.mesh.padding)
    mass_samples: int = 65536  # uniform samples for each interpolant's mass_area and crispness (0: skip)
    device: str = "auto"  # auto | cpu | cuda


register_app("interpolate", InterpolateConfig, __doc__)


def interpolate(cfg: DictConfig) -> dict[str, Any]:
    """Runs one interpolation (see the module docstring). → the report written to interpolation.json."""
    mode = str(cfg.mode)
    if mode not in MODES:
        raise ConfigError(f"mode='{mode}' must be one of {', '.join(MODES)}.")
    positive_int("steps", cfg.steps, 2)  # t runs from 0 to 1 inclusive
    positive_int("mass_samples", cfg.mass_samples, 0)
    if str(cfg.hold) not in ("a", "b"):
        raise ConfigError(f"hold='{cfg.hold}' must be a or b.")
    module = load_for_app(cfg)
    a = module.check_shape_index(cfg.a, "a")
    b = module.check_shape_index(cfg.b, "b")
    held = a if str(cfg.hold) == "a" else b
    # hold=b's default folder its own (hold=a and hold=b overwrote each other); a grid holds nothing
    suffix = "_hold_b" if mode != "grid" and str(cfg.hold) == "b" else ""
    out_dir = app_out_dir(cfg, f"interpolation_{mode}_{a}_{b}{suffix}")
    ts = np.linspace(0.0, 1.0, int(cfg.steps))
    za, zb = module.latent(a), module.latent(b)
    loops_a, loops_b = module.shape_loops(a), module.shape_loops(b)
    names = list(module.hparams.shape_names)
    if mode == "latent":
        grid = [(t, None) for t in ts]
    elif mode == "boundary":
        grid = [(None, t) for t in ts]
    else:
        grid = [(tl, tb) for tl in ts for tb in ts]
    records = []
    for k, (tl, tb) in enumerate(grid):
        z = module.latent(held) if tl is None else (1.0 - tl) * za + tl * zb
        loops = module.shape_loops(held) if tb is None else interpolate_loops(loops_a, loops_b, float(tb))
        if mode == "grid":
            i, j = divmod(k, len(ts))
            stem, title = f"grid_{i:02d}_{j:02d}", f"latent {tl:.2f}, boundary {tb:.2f}"
        else:
            t = tl if tb is None else tb
            stem, title = f"{mode}_{k:02d}", f"{mode} t = {t:.2f}"
        rec = mesh_and_measure(module, z, loops, [a, b], out_dir, stem, int(cfg.mass_samples), seed=k)
        # the member is a training shape when its code and its boundary are the same shape's own
        code_of = held if tl is None else {0.0: a, 1.0: b}.get(float(tl))
        boundary_of = held if tb is None else {0.0: a, 1.0: b}.get(float(tb))
        rec.update({"t_latent": None if tl is None else float(tl), "t_boundary": None if tb is None else float(tb),
                    "title": title, "training_shape": code_of is not None and code_of == boundary_of})
        log.info("%s: boundary_error %s", stem, rec["boundary_error"])
        records.append(rec)
    # what a member's area is compared with (``vanished``): the two end shapes under their own code and boundary,
    # meshed in the same cube; a grid's corners (0, 0) and (1, 1) are those meshes already
    if mode == "grid":
        reference = [records[0]["mesh_area"], records[-1]["mesh_area"]]
    else:
        ends = [(module.member(module.latent(i), lp), module.meshing_bounds([a, b], lp))
                for i, lp in ((a, loops_a), (b, loops_b))]
        reference = [module.mesh_member(member, box).mesh.area for member, box in ends]
    mark_vanished(records, reference)
    info = {"mode": mode, "a": a, "b": b, "a_name": names[a], "b_name": names[b], "steps": int(cfg.steps),
            "hold": str(cfg.hold), "ckpt_path": str(cfg.ckpt_path)}
    report = write_outputs(out_dir, records, info, len(ts), "interpolation.png", "interpolation.json")
    print(f"wrote {len(records)} meshes, interpolation.png and interpolation.json to {out_dir}"
          f" ({report['meshes_closed_on_boundary']} closed on Γ, {report['meshes_vanished']} vanished)")
    return report


@hydra.main(version_base="1.3", config_path=None, config_name="interpolate")
def main(cfg: DictConfig) -> None:
    run_app(interpolate, cfg)


if __name__ == "__main__":
    main()
