"""What a family's final evaluation writes: each member measured against its target mesh (UCD, paper Tab. 1),
the per-shape table, the picture of members above their targets, and the family's metrics."""

from __future__ import annotations

import csv
import logging
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from deepcurrents.eval.metrics import mesh_summary, unidirectional_chamfer
from deepcurrents.eval.plots import plot_mesh_pairs
from deepcurrents.geometry.meshes import write_mesh

log = logging.getLogger(__name__)


@dataclass
class EvaluatedMember:
    """One evaluated member of a family: its row of ``per_shape.csv``, its mesh, its boundary (B arrays (M_b, 3)),
    the picture's title and the target mesh it was measured against."""

    row: dict[str, Any]
    mesh: trimesh.Trimesh
    loops: list[np.ndarray]
    title: str
    target: trimesh.Trimesh


def meshing_cube(boxes: Sequence[np.ndarray], padding: float) -> np.ndarray:
    """The cube around the union of ``boxes`` (each (2, 3)), of side (1 + 2·padding) × its largest extent, clipped
    to the domain [-1, 1]^3. A cube rather than the tight box: a learned (or interpolated) surface may leave the
    target's box, and a thin box would hide spurious sheets from the UCD. → (2, 3)."""
    lo = np.min([b[0] for b in boxes], 0)
    hi = np.max([b[1] for b in boxes], 0)
    half = 0.5 * (1.0 + 2.0 * padding) * float((hi - lo).max()) + 1e-3
    centre = 0.5 * (lo + hi)
    return np.stack([np.maximum(centre - half, -1.0), np.minimum(centre + half, 1.0)])


def measure_member(result: Any, loops: list[np.ndarray], target: trimesh.Trimesh, path: Path, samples: int,
                   seed: int) -> tuple[dict[str, Any], trimesh.Trimesh]:
    """Writes a member's extracted surface (``result``, a ``MeshingResult``) to ``path`` and measures it against
    ``target``: UCD (target → mesh), ucd_reverse (mesh → target, which sees spurious sheets), boundary adherence,
    areas; ``samples`` uniform samples drawn with ``seed``. → (row, mesh)."""
    mesh = result.mesh
    write_mesh(mesh, path)
    empty = len(mesh.faces) == 0
    summary = mesh_summary(result, loops)
    row = {
        "ucd": None if empty else unidirectional_chamfer(target, mesh, samples, seed),
        "ucd_reverse": None if empty else unidirectional_chamfer(mesh, target, samples, seed),
        "boundary_error": summary["boundary_error"], "mesh_faces": summary["mesh_faces"],
        "mesh_area": summary["mesh_area"], "target_area": float(target.area),
        "boundary_loops_closed": summary["boundary_loops_closed"],
    }
    return row, mesh


def write_per_shape_table(members: Sequence[EvaluatedMember], path: Path) -> None:
    """``per_shape.csv``: one row per evaluated member (training shapes first, then the held-out ones)."""
    rows = [m.row for m in members]
    with open(path, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def plot_members(members: Sequence[EvaluatedMember], num_training: int, path: Path) -> None:
    """``meshes.png``: up to 12 members, each above its target, up to 4 of them held out."""
    keep_held = min(len(members) - num_training, 4)
    shown = list(members[:num_training][:12 - keep_held]) + list(members[num_training:num_training + keep_held])
    plot_mesh_pairs([m.mesh for m in shown], [m.target for m in shown], [m.loops for m in shown], path,
                    titles=[m.title for m in shown])


def _warn_empty(rows: Sequence[dict[str, Any]], split: str) -> None:
    """A warning naming the shapes that meshed empty: the means are over the others, and would flatter the run."""
    empty = [r["name"] for r in rows if r["ucd"] is None]
    if empty:
        log.warning("%d of %d %s shapes meshed empty (%s): ucd and boundary_error are over the other %d; "
                    "metrics.json counts them in empty_meshes%s.", len(empty), len(rows), split,
                    ", ".join(empty[:5]) + (", ..." if len(empty) > 5 else ""), len(rows) - len(empty),
                    "" if split == "training" else "_held_out")


def family_metrics(members: Sequence[EvaluatedMember], num_training: int, num_shapes: int,
                   loss: float | None, latent_fit_seconds: float) -> dict[str, Any]:
    """The family's metrics: means and worst cases of UCD and boundary error over the training shapes evaluated
    (the first ``num_training`` members) and, when there are any, over the held-out ones."""
    train_rows = [m.row for m in members[:num_training]]
    held_rows = [m.row for m in members[num_training:]]
    _warn_empty(train_rows, "training")
    _warn_empty(held_rows, "held-out")
    ucd = [r["ucd"] for r in train_rows if r["ucd"] is not None]
    be = [r["boundary_error"] for r in train_rows if r["boundary_error"] is not None]
    metrics: dict[str, Any] = {
        "loss": loss,
        "ucd": float(np.mean(ucd)) if ucd else None,
        "ucd_worst": float(np.max(ucd)) if ucd else None,
        "ucd_worst_index": int(train_rows[int(np.argmax([r["ucd"] if r["ucd"] is not None else -1
                                                         for r in train_rows]))]["index"]) if ucd else None,
        "ucd_reverse": float(np.mean([r["ucd_reverse"] for r in train_rows if r["ucd_reverse"] is not None]))
        if ucd else None,
        "boundary_error": float(np.mean(be)) if be else None,
        "boundary_error_worst": float(np.max(be)) if be else None,
        "empty_meshes": sum(r["ucd"] is None for r in train_rows),
        "shapes_evaluated": num_training,
        "num_shapes": num_shapes,
    }
    if held_rows:
        held_ucd = [r["ucd"] for r in held_rows if r["ucd"] is not None]
        held_be = [r["boundary_error"] for r in held_rows if r["boundary_error"] is not None]
        metrics.update({
            "ucd_held_out_mean": float(np.mean(held_ucd)) if held_ucd else None,
            "ucd_held_out_worst": float(np.max(held_ucd)) if held_ucd else None,
            "boundary_error_held_out": float(np.mean(held_be)) if held_be else None,
            "empty_meshes_held_out": sum(r["ucd"] is None for r in held_rows),
            "held_out_shapes": len(held_rows),
            "latent_fit_seconds": latent_fit_seconds,
        })
    return metrics
