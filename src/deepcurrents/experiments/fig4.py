"""Paper Fig. 4: minimal currents of the grid method (Wang & Chern 2021) beside DeepCurrents.

The report of ``experiment=fig4`` (a suite, see ``deepcurrents.experiments.tables``): its members are named
``<method>_<curve>`` (method ``grid`` or ``network``) and each wrote ``metrics.json``, ``mesh.ply`` and
``checkpoints/last.ckpt``. It writes ``fig4.png`` (one row per curve, the two methods side by side,
rendered by ``plot_mesh`` with the same camera, framing and colours) and ``fig4.csv`` / ``fig4.md``.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import matplotlib.pyplot as plt
import numpy as np
import torch
import trimesh

from deepcurrents.eval.plots import figure_pixels, mesh_view, plot_mesh
from deepcurrents.experiments.tables import write_table
from deepcurrents.models.loading import read_checkpoint

log = logging.getLogger(__name__)

METHODS = {"grid": "Wang & Chern (grid)", "network": "DeepCurrents"}
COLUMNS = ["method", "curve", "parameters", "mass_area", "mesh_area", "mesh_area_polished", "mesh_area_extrapolated",
           "mesh_area_smooth_curve", "surface", "boundary_error", "seconds"]
# the boundary's own tensors in a checkpoint's state_dict: not parameters of the representation
BOUNDARY_BUFFERS = ("vertices", "loop_sizes", "poles", "signs")


def split_name(name: str) -> tuple[str, str]:
    """``grid_trefoil`` → ("grid", "trefoil")."""
    method, _, curve = name.partition("_")
    return method, curve or name


def representation_size(state_dict: dict[str, torch.Tensor]) -> int:
    """Numbers that define the current: every tensor of ``current.*`` but the boundary's (for the network:
    trainable weights + frozen Fourier frequencies, the paper's 725,249; for the grid: N³)."""
    return int(sum(v.numel() for k, v in state_dict.items()
                   if k.startswith("current.") and k.rsplit(".", 1)[-1] not in BOUNDARY_BUFFERS))


def load_member(result: dict[str, Any]) -> dict[str, Any]:
    """Mesh, boundary loops and table row of one suite member."""
    run_dir = Path(result["dir"])
    metrics = result.get("metrics") or {}
    method, curve = split_name(result["name"])
    ckpt = read_checkpoint(run_dir / "checkpoints" / "last.ckpt")  # tensors and plain data only
    loops = [np.asarray(lp, dtype=np.float64) for lp in ckpt["hyper_parameters"]["boundary"]["loops"]]
    mesh_path = run_dir / "mesh.ply"
    mesh = trimesh.load(mesh_path, process=False) if mesh_path.is_file() else None
    if mesh is None or not isinstance(mesh, trimesh.Trimesh):
        mesh = trimesh.Trimesh(np.zeros((0, 3)), np.zeros((0, 3), dtype=int))
    row = {
        "method": method,
        "curve": curve,
        "parameters": metrics.get("parameters", representation_size(ckpt["state_dict"])),
        "mass_area": metrics.get("mass_area"),
        "mesh_area": metrics.get("mesh_area"),
        # the mesh finished by the area flow (eval.meshing.polish; minimal surfaces of the current, not the grid's)
        "mesh_area_polished": metrics.get("mesh_area_polished"),
        "mesh_area_extrapolated": metrics.get("mesh_area_extrapolated"),
        "mesh_area_smooth_curve": metrics.get("mesh_area_smooth_curve"),
        "surface": metrics.get("surface"),
        "boundary_error": metrics.get("boundary_error"),
        # the grid's α sampling is part of its cost (the network pays for α at every step)
        "seconds": metrics.get("seconds", metrics.get("train_seconds")),
    }
    return {"method": method, "curve": curve, "mesh": mesh, "loops": loops, "row": row,
            "resolution": metrics.get("resolution")}


def render_panel(mesh: trimesh.Trimesh, loops: list[np.ndarray], title: str, size: float = 4.0) -> np.ndarray:
    """One mesh by ``plot_mesh``, framed by Γ alone (so both methods share the camera) → RGB image."""
    fig = plot_mesh(mesh, loops, path=None, title=title, size=size, view=mesh_view(loops, margin=1.15))
    return np.ascontiguousarray(figure_pixels(fig)[..., :3])


def write_fig4(out_dir: str | Path, results: list[dict[str, Any]], cfg=None) -> list[dict[str, Any]]:
    """The suite report: ``fig4.png`` and the table ``fig4.csv`` / ``fig4.md``. → table rows."""
    out_dir = Path(out_dir)
    members = [load_member(r) for r in results]
    rows = [m["row"] for m in members]
    write_table(out_dir, [{"name": m["curve"], "metrics": m["row"]} for m in members], columns=COLUMNS,
                name="fig4")
    curves = list(dict.fromkeys(m["curve"] for m in members))
    methods = [k for k in METHODS if any(m["method"] == k for m in members)]
    methods += sorted({m["method"] for m in members} - set(methods))
    fig, axes = plt.subplots(len(curves), len(methods), figsize=(4 * len(methods), 4 * len(curves)), dpi=120,
                             squeeze=False)
    for ax in axes.flat:
        ax.set_axis_off()
    for m in members:
        i, j = curves.index(m["curve"]), methods.index(m["method"])
        label = METHODS.get(m["method"], m["method"])
        if m["method"] == "grid" and m["resolution"]:
            label += f" {m['resolution']}³"
        area = f"area {m['mesh'].area:.4f}" if len(m["mesh"].faces) else "no surface"
        axes[i, j].imshow(render_panel(m["mesh"], m["loops"], f"{m['curve']} — {label}\n{area}"))
    fig.tight_layout()
    fig.savefig(out_dir / "fig4.png")
    plt.close(fig)
    log.info("Fig. 4 written to %s (fig4.png, fig4.csv, fig4.md)", out_dir)
    return rows
