"""Metrics of any checkpoint, optionally against a target surface:
``python -m deepcurrents.cli.evaluate ckpt_path=…/last.ckpt [target=path/to/mesh.ply] [mesh=path/to/own.ply]``.

Writes ``metrics.json`` (in a folder named after the checkpoint beside it, or ``out_dir=``):

- ``loss`` = E|ω| over the domain (Monte Carlo, ``mass_samples``) and the extraction-free area bound
  ``mass_area`` (``mass_length`` in 2D) with its standard error;
- 3D: ``mesh_area``, ``mesh_faces``, ``boundary_error`` of the extracted surface (or of ``mesh=``);
- with ``target=``: ``ucd`` = E_{y ~ U(target)} dist(y, mesh) (the paper's UCD, ``samples`` uniform points),
  ``ucd_reverse`` (mesh → target) and ``chamfer`` (their mean), in the meshes' units; without it, a
  reconstruction's checkpoint is scored against the target it carries (a mesh or a point cloud), as its run was.

A run that normalised its curve or target (data.normalize): ``target=`` and ``mesh=`` are in the input's units (as
the run's own mesh.ply) and move into the model's frame, where the numbers are computed, as the run's were;
``ucd_input_units`` and ``ucd_reverse_input_units`` give the distances in the files' units, and the mesh written here
is in the input's units.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import hydra
import numpy as np
import trimesh
from omegaconf import MISSING, DictConfig

from deepcurrents.cli.common import output_dir, register_app, run_app
from deepcurrents.errors import ConfigError, positive_int
from deepcurrents.eval.meshing import extract_curve_2d, extract_surface
from deepcurrents.eval.metrics import (
    curve_length,
    mass_estimate,
    mass_estimate_settings,
    mass_to_area,
    mesh_summary,
    metrics_json,
    unidirectional_chamfer,
)
from deepcurrents.geometry.meshes import read_mesh, write_mesh
from deepcurrents.models.current_module import input_mesh
from deepcurrents.models.loading import (
    file_frame,
    load_module,
    mesh_settings,
    resolve_device,
    run_evaluation,
    viewable_current,
)
from deepcurrents.models.reconstruction import carries_target, input_unit_distances, reconstruction_metrics

log = logging.getLogger("deepcurrents.evaluate")


@dataclass
class EvaluateConfig:
    ckpt_path: str = MISSING
    target: str | None = None  # a triangle mesh (.ply, .obj, .off, …) to measure the UCD against
    mesh: str | None = None  # measure this mesh instead of extracting one from the checkpoint
    out_dir: str | None = None
    device: str = "auto"
    shape: int | None = None  # families: which training shape (default 0)
    resolution: int | None = None  # marching cubes (default: the run's evaluation.mesh.resolution)
    samples: int | None = None  # uniform samples of each surface for the Chamfer distances (None: the run's
    # evaluation.ucd_samples, 100000 by default)
    mass_samples: int | None = None  # None: the run's evaluation.mass_samples and mass_rel_stderr stop
    seed: int | None = None  # None: the run's evaluation.seed


register_app("evaluate", EvaluateConfig, __doc__)


def evaluate_checkpoint(cfg: DictConfig) -> dict:
    """The app's body. → the metrics written to metrics.json."""
    if cfg.samples is not None:
        positive_int("samples", cfg.samples)
    if cfg.mass_samples is not None:
        positive_int("mass_samples", cfg.mass_samples)
    if cfg.resolution is not None:
        positive_int("resolution", cfg.resolution, 8)
    target = read_mesh(cfg.target, "target") if cfg.target else None
    given = read_mesh(cfg.mesh, "mesh") if cfg.mesh else None
    device = resolve_device(cfg.device)
    module = load_module(cfg.ckpt_path, map_location=device)
    current = viewable_current(module, cfg.ckpt_path, cfg.shape)
    out = output_dir(cfg.ckpt_path, cfg.out_dir, cfg.shape)

    # unset sizes and seed from the run's own evaluation settings, so `loss` matches its metrics.json
    evaluation = run_evaluation(module)
    seed = int(cfg.seed) if cfg.seed is not None else int(evaluation.get("seed", 0))
    samples = int(cfg.samples) if cfg.samples is not None else int(evaluation.get("ucd_samples", 100_000))
    mesh = None
    # a run that normalised its curve or target: files given here are in the input's units, as the run's mesh.ply
    # is, and move into the model's frame, where the current's numbers are
    frame = file_frame(module)
    if frame is not None:
        given, target = (None if m is None else trimesh.Trimesh((np.asarray(m.vertices) - frame[1]) / frame[0],
                                                                m.faces, process=False) for m in (given, target))
    if current.dim == 3:  # the mesh first: with evaluation.mass_refine_mesh the mass estimate refines its cells
        if given is not None:
            mesh = given
        else:
            mesh = extract_surface(current, **mesh_settings(module, cfg.shape, resolution=cfg.resolution)).mesh
            write_mesh(mesh if frame is None else input_mesh(mesh, frame), out / "mesh.ply")
    # the run's own estimate (its sample count, early stop, refinement near Γ and its mesh, tube about Γ), or exactly
    # mass_samples
    settings = mass_estimate_settings(evaluation, mesh)
    if cfg.mass_samples is not None:
        settings.update(num_samples=int(cfg.mass_samples), rel_stderr=None)
    mass, stderr = mass_estimate(current, seed=seed, **settings)
    scale = mass_to_area(1.0, current.dim, current.alpha_scale)
    name = "area" if current.dim == 3 else "length"
    metrics: dict = {
        "ckpt_path": str(cfg.ckpt_path),
        **({} if cfg.shape is None else {"shape": int(cfg.shape)}),
        "steps": int(getattr(module, "loaded_step", 0)),
        "loss": mass,
        f"mass_{name}": mass * scale,
        f"mass_{name}_stderr": stderr * scale,
    }
    if current.dim == 2:
        if target is not None or given is not None:
            raise ConfigError("target= and mesh= are for 3D currents; this checkpoint's current is 2D.")
        # the run's own curve settings (a metric-trained curve keeps the level set: recon_2d_semicircle)
        metrics["curve_length"] = curve_length(extract_curve_2d(current, **dict(evaluation.get("curve") or {})))
    else:
        metrics["mesh"] = str(cfg.mesh) if given is not None else str(out / "mesh.ply")
        loops = [lp.detach().cpu().double().numpy() for lp in current.loops]
        metrics.update(mesh_summary(mesh, loops))
        if target is not None:
            metrics["target"] = str(cfg.target)
            if len(mesh.faces) == 0:
                log.warning("The extracted mesh is empty: its distances to the target are undefined.")
                metrics.update(ucd=None, ucd_reverse=None, chamfer=None)
            else:  # in the model's frame, so that ucd matches the run's metrics.json
                ucd = unidirectional_chamfer(target, mesh, samples, seed)
                reverse = unidirectional_chamfer(mesh, target, samples, seed)
                metrics.update(ucd=ucd, ucd_reverse=reverse, chamfer=0.5 * (ucd + reverse))
        elif carries_target(module):  # the run's own target, in the model's frame, scored as the run scored it
            metrics["target"] = "the checkpoint's own"  # its file's name is in the run's metrics.json, not the tensors
            log.info("No target= given: the mesh is scored against the target this checkpoint carries.")
            metrics.update(reconstruction_metrics(module, mesh, samples, seed))
        if frame is not None and "ucd" in metrics:
            metrics.update(input_unit_distances(metrics, frame[0]))
    (out / "metrics.json").write_text(metrics_json(metrics))
    return metrics


@hydra.main(version_base="1.3", config_path=None, config_name="evaluate")
def main(cfg: DictConfig) -> None:
    metrics = run_app(evaluate_checkpoint, cfg)
    print(metrics_json(metrics))


if __name__ == "__main__":
    main()
