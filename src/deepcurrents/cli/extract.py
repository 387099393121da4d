"""The surface of any 3D checkpoint as a mesh at any resolution:
``python -m deepcurrents.cli.extract ckpt_path=…/last.ckpt resolution=256 [format=obj]``.

Uses the run's own meshing settings (``evaluation.mesh``: the method, by default the current's phase for
minimal surfaces and the grid and the paper's level set f = s for reconstructions and families; the |ω|
cut; the tube closed onto Γ; see ``eval.meshing``); any of them can be overridden here.
Writes ``mesh_r<resolution>.<format>`` (+ a picture) in a folder named after the checkpoint beside it; a 2D
current gives its curve instead, ``curve_r<resolution>.npz`` (one (K, 2) polyline per array).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import hydra
import numpy as np
from omegaconf import MISSING, DictConfig

from deepcurrents.cli.common import output_dir, register_app, run_app
from deepcurrents.errors import ConfigError, number_at_least, number_between, positive_int
from deepcurrents.eval.meshing import MESH_METHOD_CHOICES, extract_curve_2d, extract_surface
from deepcurrents.eval.metrics import curve_length, mesh_summary, metrics_json
from deepcurrents.eval.render import Camera, render_mesh
from deepcurrents.geometry.meshes import write_mesh
from deepcurrents.models.current_module import input_mesh, metrics_in_input_units
from deepcurrents.models.loading import (
    file_frame,
    load_module,
    mesh_settings,
    resolve_device,
    run_evaluation,
    viewable_current,
)

log = logging.getLogger("deepcurrents.extract")

FORMATS = ("ply", "obj", "off", "stl", "glb")
# settings of a surface's meshing that a 2D current's curve has no counterpart for
SURFACE_ONLY = ("close_boundary", "newton_steps", "min_component", "padding", "strip_rows", "level_blend")


@dataclass
class ExtractConfig:
    ckpt_path: str = MISSING
    out_dir: str | None = None
    device: str = "auto"
    shape: int | None = None  # families: which training shape (default 0)
    resolution: int = 256  # marching-cubes cells along the longest side of the meshed region
    format: str = "ply"  # ply | obj | off | stl | glb
    picture: bool = True  # also a PNG of the mesh
    # None: the run's evaluation.mesh value
    delta: float | None = None
    boundary_tube: float | None = None
    close_boundary: bool | None = None
    newton_steps: int | None = None
    method: str | None = None  # phase | level_set (the paper's f = s) | auto (the model kind's own)
    min_alignment: float | None = None  # level_set: keep faces with cos(ω, ∇f) ≥ this (-1: off)
    min_component: float | None = None  # drop pieces below this fraction of the area (0: off)
    padding: float | None = None  # the meshed box: Γ's bounding box grown by this
    strip_rows: int | None = None  # rows of the strip from the cut border to Γ (None: the run's, else by method)
    level_blend: float | None = None  # level_set: the level follows f along Γ within this distance (0: one level)


register_app("extract", ExtractConfig, __doc__)


def extract_checkpoint(cfg: DictConfig) -> dict:
    """The app's body. → a summary (paths, area, faces, boundary error)."""
    positive_int("resolution", cfg.resolution, 8)
    if cfg.strip_rows is not None:
        positive_int("strip_rows", cfg.strip_rows)
    for key in ("delta", "boundary_tube"):  # as training refuses them (experiments.config.validate_config)
        if cfg.get(key) is not None:
            number_at_least(key, cfg.get(key))
    if cfg.get("newton_steps") is not None:
        positive_int("newton_steps", cfg.newton_steps, 0)
    fmt = str(cfg.format).lower().lstrip(".")
    if fmt not in FORMATS:
        raise ConfigError(f"format='{cfg.format}' must be one of {', '.join(FORMATS)}.")
    for key, lo, hi in (("min_alignment", -1.0, 1.0), ("min_component", 0.0, 1.0), ("padding", 0.0, 1.0),
                        ("level_blend", 0.0, float("inf"))):
        if cfg.get(key) is not None:
            number_between(key, cfg.get(key), lo, hi)
    if cfg.method is not None and cfg.method not in MESH_METHOD_CHOICES:
        raise ConfigError(f"method='{cfg.method}' must be one of {', '.join(MESH_METHOD_CHOICES)}.")
    device = resolve_device(cfg.device)
    module = load_module(cfg.ckpt_path, map_location=device)
    current = viewable_current(module, cfg.ckpt_path, cfg.shape)
    out = output_dir(cfg.ckpt_path, cfg.out_dir, cfg.shape)  # before meshing: an unwritable folder is said at once
    if current.dim == 2:  # a 2D current's "surface" is a curve: its polylines, like the run's curve.npz
        return extract_curve(module, current, cfg, out, fmt)
    settings = mesh_settings(module, cfg.shape, resolution=cfg.resolution, delta=cfg.delta,
                             boundary_tube=cfg.boundary_tube, close_boundary=cfg.close_boundary,
                             newton_steps=cfg.newton_steps, method=cfg.method, min_alignment=cfg.min_alignment,
                             min_component=cfg.min_component, padding=cfg.padding, strip_rows=cfg.strip_rows,
                             level_blend=cfg.level_blend)
    result = extract_surface(current, **settings)
    mesh = result.mesh
    stem = f"mesh_r{cfg.resolution}"
    path = out / f"{stem}.{fmt}"
    loops = [lp.detach().cpu().double().numpy() for lp in current.loops]
    summary = {"mesh": str(path), "resolution": int(cfg.resolution), **mesh_summary(result, loops)}
    if cfg.shape is not None:
        summary["shape"] = int(cfg.shape)
    # a curve or target that data.normalize moved into the box: the mesh and its numbers in the file's coordinates,
    # as the run's own mesh.ply
    frame = file_frame(module)
    if frame is not None:
        write_mesh(input_mesh(mesh, frame), path)
        if getattr(module, "target_scale", None) is not None:  # a reconstruction's keys, as in its metrics.json
            summary["mesh_area_input_units"] = summary["mesh_area"] * frame[0] ** 2
        else:  # a minimal surface's: the plain keys in the curve's units, the model's as <key>_normalized
            summary = metrics_in_input_units(summary, *frame)
    else:
        write_mesh(mesh, path)
    (out / f"{stem}.json").write_text(metrics_json(summary))
    if cfg.picture:
        render_mesh(mesh, loops, Camera(width=480, height=480), out / f"{stem}.png",
                    title=f"area {summary['mesh_area']:.4g}, {len(mesh.faces)} faces")  # as its JSON says
        summary["picture"] = str(out / f"{stem}.png")
    return summary


def extract_curve(module, current, cfg: DictConfig, out: Path, fmt: str = "ply") -> dict:
    """A 2D current's curve at ``cfg.resolution`` (the run's ``evaluation.curve`` settings otherwise):
    ``out/curve_r<resolution>.npz`` (one (K, 2) polyline per array) and its summary."""
    settings = {**dict(run_evaluation(module).get("curve") or {}), "resolution": int(cfg.resolution)}
    # the curve's own settings (evaluation.curve) take the app's values; the surface-only ones cannot apply
    settings.update({k: cfg[k] for k in ("delta", "boundary_tube", "min_alignment") if cfg[k] is not None})
    if cfg.method not in (None, "auto"):  # phase | level_set, checked above
        settings["method"] = cfg.method
    ignored = [k for k in SURFACE_ONLY if cfg[k] is not None] + (["format"] if fmt != "ply" else [])
    if ignored:
        log.warning("%s: a 2D current's curve is written as curve_r%d.npz; %s apply to surfaces only and were not "
                    "used.", cfg.ckpt_path, int(cfg.resolution), ", ".join(ignored))
    curves = extract_curve_2d(current, **settings)
    path = out / f"curve_r{cfg.resolution}.npz"
    np.savez(path, *curves)
    summary = {"curve": str(path), "resolution": int(cfg.resolution), "curve_length": curve_length(curves),
               "pieces": len(curves)}
    (out / f"curve_r{cfg.resolution}.json").write_text(metrics_json(summary))
    return summary


@hydra.main(version_base="1.3", config_path=None, config_name="extract")
def main(cfg: DictConfig) -> None:
    summary = run_app(extract_checkpoint, cfg)
    print(metrics_json(summary))


if __name__ == "__main__":
    main()
