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

Two families that share a loop (a hand family and a forearm family trained on ``make data``'s joined parts,
``data/anny/joined/wrist.L``) are generated together and stitched along it::

    python -m deepcurrents.cli.generate ckpt_path=hands/…/last.ckpt curve=hand.L.obj latent=3 \
        neighbour_ckpt=forearms/…/last.ckpt neighbour_curve=forearm.L.obj

The loops the two curve files both hold (the wrist, to 1e-6 of the curves' size) are the seams; the neighbour is
written as ``<name>_neighbour.*`` and the two as one mesh, ``<name>_stitched.ply`` and ``.png``, whose seam vertices
lie on the shared loop and are used by both sides (the JSON's ``stitched``: border edges, manifold, seams).
``rotate`` (degrees about ``axis``, default the loop's longest in-plane direction), ``scale`` and ``translate`` move
the shared loop about its centroid first, in both files alike. With ``carry=true`` (the default, as
``deepcurrents-edit-body``'s) the member of ``ckpt_path``, the part beyond the loop, is generated on its own loop and
moved with it; the neighbour is generated for the moved loop. ``carry=false`` generates both for the moved loop.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import hydra
import numpy as np
import trimesh
from omegaconf import MISSING, DictConfig, OmegaConf

from deepcurrents.cli.common import plain_file_name, register_app, run_app
from deepcurrents.cli.families import app_out_dir, load_for_app, mesh_and_measure, write_outputs
from deepcurrents.data.body_edit import LoopMove
from deepcurrents.data.human_parts import DatasetError
from deepcurrents.errors import ConfigError
from deepcurrents.eval.meshing.stitch import SharedLoop, stitch_parts
from deepcurrents.experiments.stitched import draw_body, seam_report
from deepcurrents.geometry.correspondence import align_loops
from deepcurrents.geometry.curves import load_boundary, write_curve_file
from deepcurrents.geometry.meshes import write_mesh
from deepcurrents.geometry.topology import consistently_oriented

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
    neighbour_ckpt: str | None = None  # a second family that shares a loop with this one: generated and stitched
    neighbour_curve: str | None = None  # its boundary (holding the shared loop as ``curve`` does)
    neighbour_latent: int | None = None  # its training shape's code (default: ``latent``)
    # with a neighbour: the shared loop moved about its centroid before both are generated (as deepcurrents-edit-body)
    rotate: float = 0.0  # degrees about ``axis``
    axis: list[float] | None = None  # default: the loop's longest in-plane direction (a wrist's or elbow's hinge)
    scale: float = 1.0  # the shared loop's own scale (curve_scale scales whole files)
    translate: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    carry: bool = True  # the member of ``ckpt_path`` (the part beyond the loop: the hand) moves with the loop as it
    # is (generated on its own loop, then moved); false: it is generated for the moved loop too


register_app("generate", GenerateConfig, __doc__)


def generate(cfg: DictConfig) -> dict[str, Any]:
    """Meshes the family member (z_latent, Γ from the curve file), and with ``neighbour_ckpt`` the neighbour's member,
    stitched to it along the loops they share. → the report written to <name>.json."""
    if not float(cfg.curve_scale) > 0:
        raise ConfigError(f"curve_scale={cfg.curve_scale} must be positive.")
    given = plain_file_name(cfg.name)
    if (cfg.get("neighbour_ckpt") is None) != (cfg.get("neighbour_curve") is None):
        raise ConfigError("neighbour_ckpt and neighbour_curve go together: the neighbour family and its boundary.")
    translate = [float(t) for t in cfg.translate]
    if len(translate) != 3:
        raise ConfigError(f"translate={list(cfg.translate)} must be three numbers [x, y, z].")
    move = LoopMove(float(cfg.rotate), None if cfg.axis is None else list(cfg.axis), float(cfg.scale), translate)
    moved = move.rotate != 0 or move.scale != 1 or any(t != 0 for t in translate)
    if moved and cfg.get("neighbour_ckpt") is None:
        raise ConfigError("rotate, axis, scale and translate move the loop two members share; give neighbour_ckpt "
                          "and neighbour_curve (or edit the curve file itself).")
    name = given or f"{Path(str(cfg.curve)).stem}_latent{cfg.latent}"
    out_dir = app_out_dir(cfg, "generated")
    if cfg.get("neighbour_ckpt") is None:
        rec, info = _member(cfg, _curve_loops(cfg, "curve"), "curve", "latent", out_dir, name)
        report = write_outputs(out_dir, [rec], info, 1, f"{name}.png", f"{name}.json")
        print(f"wrote {name}.ply, {name}.png and {name}.json to {out_dir} (boundary_error {rec['boundary_error']})")
        return report
    neighbour_cfg = OmegaConf.merge(cfg, {"ckpt_path": cfg.neighbour_ckpt, "curve": cfg.neighbour_curve,
                                          "latent": cfg.latent if cfg.neighbour_latent is None
                                          else cfg.neighbour_latent})
    own, theirs = _curve_loops(cfg, "curve"), _curve_loops(neighbour_cfg, "neighbour_curve")
    pairs = matching_loops(own, "curve", cfg.curve, theirs, cfg.neighbour_curve, "neighbour_curve")  # before meshing
    carry = moved and bool(cfg.carry)
    if carry and len(pairs) > 1:
        raise ConfigError(f"carry=true moves the member of ckpt_path with the loop it shares, but the curves share "
                          f"{len(pairs)} loops; give carry=false to generate both members for the moved loops.")
    pivot = own[pairs[0][0]].copy()
    unmoved = list(own)
    if moved:  # the same similarity (about the loop's centroid) on both files' copies, which stay identical
        try:
            for i, j in pairs:
                own[i], theirs[j] = move.apply(own[i], own[i]), move.apply(theirs[j], own[i])
        except DatasetError as err:
            raise ConfigError(str(err)) from None
    loops = [SharedLoop(f"shared{i}", ("generated", "neighbour"), np.asarray(own[i], np.float64)) for i, _ in pairs]
    rec, info = _member(cfg, unmoved if carry else own, "curve", "latent", out_dir, name)
    if carry:  # the member as generated on its own loops, moved by the similarity (a similarity maps it exactly)
        _carry(rec, move, pivot, out_dir, name)
    other, other_info = _member(neighbour_cfg, theirs, "neighbour_curve", "neighbour_latent", out_dir,
                                f"{name}_neighbour")
    stitched = stitch_parts({"generated": rec["_mesh"], "neighbour": other["_mesh"]}, loops)
    write_mesh(stitched.mesh, out_dir / f"{name}_stitched.ply")
    draw_body(stitched, loops, out_dir / f"{name}_stitched.png")
    summary = {"surface": stitched.topology.describe() if stitched.topology else "empty",
               "border_edges": stitched.border_edges,
               "manifold": bool(stitched.topology.manifold) if stitched.topology else False,
               "consistently_oriented": consistently_oriented(np.asarray(stitched.mesh.faces)),
               "seams": seam_report(stitched, loops), "open_loops": stitched.open_loops}
    info = {**info, "neighbour": {**other_info, "boundary_error": other["boundary_error"]}, "stitched": summary}
    report = write_outputs(out_dir, [rec, other], info, 2, f"{name}.png", f"{name}.json")
    print(f"wrote {name}.ply, {name}_neighbour.ply, {name}_stitched.ply (and their pictures) and {name}.json to "
          f"{out_dir} ({summary['surface']}, {summary['border_edges']} border edges)")
    return report


def _carry(rec: dict[str, Any], move: LoopMove, pivot: np.ndarray, out_dir: Path, stem: str) -> None:
    """Moves a generated member (its mesh, loops and lengths) by ``move`` about ``pivot`` (M, 3) and rewrites its
    files."""
    mesh = rec["_mesh"]
    if len(mesh.vertices):
        mesh = trimesh.Trimesh(move.apply(np.asarray(mesh.vertices), pivot), np.asarray(mesh.faces), process=False)
    rec["_mesh"], rec["_loops"] = mesh, [move.apply(lp, pivot) for lp in rec["_loops"]]
    for key in ("mesh_area", "mesh_closed_area_dropped"):
        if rec.get(key) is not None:
            rec[key] *= move.scale ** 2
    if rec.get("boundary_error") is not None:
        rec["boundary_error"] *= move.scale
    write_mesh(mesh, out_dir / f"{stem}.ply")
    write_curve_file(out_dir / f"{stem}_boundary.obj", rec["_loops"])
    rec["carried"] = True


def _curve_loops(cfg: DictConfig, key: str) -> list[np.ndarray]:
    """The loops of ``cfg.curve`` as read (``key``: the setting, for messages)."""
    return load_boundary(str(cfg.curve), scale=float(cfg.curve_scale), setting=key).loops


def _member(cfg: DictConfig, raw_loops: list[np.ndarray], curve_key: str, latent_key: str, out_dir: Path, stem: str
            ) -> tuple[dict[str, Any], dict[str, Any]]:
    """The family member of ``cfg`` on ``raw_loops`` (its curve's, the shared loop moved) meshed, measured and
    written as ``<stem>.ply`` (its record, with its mesh and loops in memory) and what the report says of it; the
    keys name the settings in messages."""
    module = load_for_app(cfg)
    k = module.check_shape_index(cfg.latent, latent_key)
    loops = align_loops(raw_loops, module.shape_loops(k), f"{curve_key}='{cfg.curve}'")
    rec = mesh_and_measure(module, module.latent(k), loops, [k], out_dir, stem)
    rec["title"] = f"boundary error {rec['boundary_error']:.2g}" if rec["boundary_error"] is not None \
        else "empty mesh"
    info = {"curve": str(cfg.curve), "latent": k, "latent_name": list(module.hparams.shape_names)[k],
            "ckpt_path": str(cfg.ckpt_path)}
    return rec, info


def matching_loops(loops: list[np.ndarray], key: str, curve: str, other: list[np.ndarray], other_curve: str,
                 other_key: str, tolerance: float = 1e-6) -> list[tuple[int, int]]:
    """The loops that two boundaries both hold (the same points, in either direction, within ``tolerance`` of the
    curves' size): (index in ``loops``, index in ``other``) each; ConfigError naming both files when they share none."""
    size = float(np.ptp(np.concatenate([*loops, *other]), axis=0).max())
    out = []
    for i, a in enumerate(loops):
        for j, b in enumerate(other):
            if len(a) == len(b) and min(_cyclic_gap(a, b), _cyclic_gap(a, b[::-1])) <= tolerance * size:
                out.append((i, j))
                break
    if not out:
        raise ConfigError(f"{key}='{curve}' and {other_key}='{other_curve}' share no loop (the same points in both "
                          "files), so the two members cannot be stitched; give both the loop they share.")
    return out


def _cyclic_gap(a: np.ndarray, b: np.ndarray) -> float:
    """The largest distance between matched points of two closed polylines of equal size, over cyclic shifts."""
    return min(float(np.abs(a - np.roll(b, -k, 0)).max()) for k in range(len(b)))


@hydra.main(version_base="1.3", config_path=None, config_name="generate")
def main(cfg: DictConfig) -> None:
    run_app(generate, cfg)


if __name__ == "__main__":
    main()
