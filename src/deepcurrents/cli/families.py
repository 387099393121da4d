"""Plumbing shared by the family apps (``interpolate``, ``generate``): loading an autodecoder checkpoint,
meshing one member and writing the picture grid with its JSON report."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch
from omegaconf import DictConfig

from deepcurrents.cli.common import not_a_command, output_dir
from deepcurrents.errors import number_between, positive_int
from deepcurrents.eval.metrics import mass_estimate, mass_to_area, mesh_summary, metrics_json, sheet_flux
from deepcurrents.eval.plots import plot_mesh_grid
from deepcurrents.geometry.curves import write_curve_file
from deepcurrents.geometry.meshes import write_mesh
from deepcurrents.models.autodecoder import AutodecoderModule
from deepcurrents.models.loading import load_module, resolve_device


def app_out_dir(cfg: DictConfig, name: str) -> Path:
    """``cfg.out_dir``, else ``<folder named after the checkpoint>/<name>`` beside it (as the other apps)."""
    # output_dir makes the folder or says in one sentence why it cannot
    return output_dir(cfg.ckpt_path, cfg.out_dir or str(output_dir(cfg.ckpt_path, None) / name))


def load_for_app(cfg: DictConfig) -> AutodecoderModule:
    """The family model of ``cfg.ckpt_path`` on ``cfg.device``, with ``cfg.resolution`` and ``cfg.padding`` (the
    meshed cube's margin, ``AutodecoderModule.meshing_bounds``) applied to its evaluation settings."""
    padding = cfg.get("padding")
    if padding is not None:  # before loading: a mistyped setting is said at once
        padding = number_between("padding", padding, 0.0, 1.0)
    module = load_module(cfg.ckpt_path, map_location=resolve_device(str(cfg.device)), expected=AutodecoderModule)
    if cfg.get("resolution") is not None:
        resolution = positive_int("resolution", cfg.resolution, 8)
        module.evaluation["mesh"] = {**dict(module.evaluation.get("mesh", {})), "resolution": resolution}
    if padding is not None:
        module.evaluation.pop("padding", None)  # where checkpoints before the one `evaluation` node kept it
        module.evaluation["mesh"] = {**dict(module.evaluation.get("mesh", {})), "padding": padding}
    module.MESH_RESOLUTION_KEY = "resolution"  # the app's own setting, in its memory and coarse-grid sentences
    return module


def mesh_and_measure(module: AutodecoderModule, z: torch.Tensor, loops: list[np.ndarray], shapes: list[int],
                     out_dir: Path, stem: str, mass_samples: int = 0, seed: int = 0) -> dict[str, Any]:
    """Meshes the member (z, Γ), writes ``<stem>.ply`` and ``<stem>_boundary.obj``. → its record.

    With ``mass_samples`` > 0 the record also has the member's extraction-free ``mass_area`` (Euclidean
    mass E|ω| over U, in area units) and ``crispness`` = mass_area / mesh_area: about 1 for a clean sheet,
    larger for a foggy current whose mass is spread around the mesh; and ``sheet_flux``, the median of
    |∫ ω·n| across the mesh in units of the jump (``eval.metrics.sheet_flux``): about 1 for a full sheet, less
    where part of the flux crosses elsewhere (which lowers the crispness too)."""
    member = module.member(z, loops)
    result = module.mesh_member(member, module.meshing_bounds(shapes, loops))
    mesh = result.mesh
    write_mesh(mesh, out_dir / f"{stem}.ply")
    write_curve_file(out_dir / f"{stem}_boundary.obj", loops)
    summary = mesh_summary(result, loops)
    summary.pop("mesh_level")
    if mass_samples > 0:
        mass, _ = mass_estimate(member, int(mass_samples), seed=seed)
        summary["mass_area"] = mass_to_area(mass, 3, member.alpha_scale)
        area = summary.get("mesh_area")
        summary["crispness"] = summary["mass_area"] / area if area else None
        # crispness < 1 is a weaker sheet, not a cleaner one: the median flux across the mesh tells them apart
        summary["sheet_flux"] = float(np.median(sheet_flux(member, mesh, seed=seed))) if len(mesh.faces) else None
    return {"mesh": f"{stem}.ply", "boundary": f"{stem}_boundary.obj", **summary, "_mesh": mesh, "_loops": loops}


CLOSED_TOLERANCE = 1e-6  # a zipped border lies on Γ to rounding; a hole's border is voxels away


def closed_on_boundary(record: dict[str, Any]) -> bool:
    """Whether a member's mesh is closed on its Γ: every loop zipped and no other border (a hole, a tear), i.e.
    the Hausdorff distance between the mesh's whole border and Γ is ~0. Zipped loops alone do not say it: a
    torn member can zip its loop and still have a hole elsewhere."""
    zipped = record.get("boundary_loops_closed")
    error = record.get("boundary_error")
    return bool(zipped) and zipped == len(record["_loops"]) and error is not None and error <= CLOSED_TOLERANCE


VANISHED_FRACTION = 0.25  # a member with less than this of the smaller end shape's mesh area is no shape of the family


def mark_vanished(records: list[dict[str, Any]], reference_areas: list[float]) -> None:
    """Adds ``area_fraction`` (mesh area / the smaller of ``reference_areas``, the two end shapes' own meshes) and
    ``vanished`` (below ``VANISHED_FRACTION``, or empty) to each record in place: a member can be closed on its Γ
    and still be no hand, a small cap across the wrist."""
    smaller = float(min(reference_areas)) if reference_areas else 0.0
    for r in records:
        area = r.get("mesh_area") if r.get("boundary_error") is not None else 0.0
        r["area_fraction"] = float(area) / smaller if smaller > 0 and area is not None else None
        r["vanished"] = bool(r["area_fraction"] is not None and r["area_fraction"] < VANISHED_FRACTION)


def _mean(values: list[float]) -> float | None:
    return float(np.mean(values)) if values else None


def fog_summary(records: list[dict[str, Any]]) -> dict[str, Any]:
    """``crispness_per_flux_mean``: the members' mean of crispness / sheet_flux, the fog per unit of the flux the
    sheet carries (a crispness lowered by a weaker sheet does not lower it). Where some members are training shapes
    (``training_shape``: a shape's own code and boundary) and some are not, ``crispness_training_mean`` and
    ``crispness_between_mean`` (and the same per unit of flux) set the in-between members against the shapes
    the model was fitted to: fog that interpolation adds shows as between > training."""
    measured = [r for r in records if r.get("crispness") is not None and r.get("sheet_flux")]
    summary: dict[str, Any] = {"crispness_per_flux_mean": _mean([r["crispness"] / r["sheet_flux"] for r in measured])}
    training = [r for r in measured if r.get("training_shape")]
    between = [r for r in measured if r.get("training_shape") is False]
    if training and between:
        for name, group in (("training", training), ("between", between)):
            summary[f"crispness_{name}_mean"] = _mean([r["crispness"] for r in group])
            summary[f"crispness_per_flux_{name}_mean"] = _mean([r["crispness"] / r["sheet_flux"] for r in group])
    return summary


def summarise(records: list[dict[str, Any]]) -> dict[str, Any]:
    errors = [r["boundary_error"] for r in records if r["boundary_error"] is not None]
    crisp = [r["crispness"] for r in records if r.get("crispness") is not None]
    flux = [r["sheet_flux"] for r in records if r.get("sheet_flux") is not None]
    return {
        "boundary_error_mean": _mean(errors),
        "boundary_error_max": float(np.max(errors)) if errors else None,
        "empty_meshes": sum(r["boundary_error"] is None for r in records),
        "crispness_mean": _mean(crisp),
        "crispness_max": float(np.max(crisp)) if crisp else None,
        "crispness_min": float(np.min(crisp)) if crisp else None,
        "sheet_flux_mean": _mean(flux),
        "sheet_flux_min": float(np.min(flux)) if flux else None,
        **fog_summary(records),
        "meshes_closed_on_boundary": sum(closed_on_boundary(r) for r in records),
        **({"meshes_vanished": sum(bool(r["vanished"]) for r in records)} if records and "vanished" in records[0]
           else {}),
    }


def write_outputs(out_dir: Path, records: list[dict[str, Any]], info: dict[str, Any], ncols: int,
                  figure: str, json_name: str) -> dict[str, Any]:
    """The picture grid and the JSON report (records without their in-memory meshes)."""
    titles = [r["title"] for r in records]
    plot_mesh_grid([r["_mesh"] for r in records], [r["_loops"] for r in records], out_dir / figure,
                   titles=titles, ncols=ncols, size=5.0 if len(records) == 1 else 3.0)
    report = {**info, **summarise(records),
              "items": [{k: v for k, v in r.items() if not k.startswith("_")} for r in records]}
    (out_dir / json_name).write_text(metrics_json(report))
    return report


if __name__ == "__main__":
    not_a_command("deepcurrents.cli.families")
