"""A whole body from reconstructed parts that share their boundary curves (``experiment=stitched_body``): each part of
a body folder (``data.body_partition``) is reconstructed with its shared loops as Γ, one suite member per part, and
the report stitches the parts' meshes along the loops (``eval.meshing.stitch``) into ``body.ply``, measures it
against the body and draws it with its seams. ``edit_body`` moves one loop of a stitched body (``data.body_edit``)
and refits the parts it deforms from their checkpoints (``deepcurrents-edit-body``).

Written into the suite's folder: ``body.ply`` (the stitched mesh, in the body's frame), ``body.png`` (front and back,
seams in black), ``stitched.json`` (topology, border edges, seams, the whole-body and per-part UCDs) and
``stitched.md`` (the per-part table and the whole body's row).
"""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path
from typing import Any

import numpy as np
import trimesh
from omegaconf import OmegaConf

from deepcurrents.data.body_partition import StitchedBody, read_body
from deepcurrents.errors import UserInputError
from deepcurrents.eval.meshing.stitch import SharedLoop, StitchedMesh, loop_parameter, stitch_parts
from deepcurrents.eval.metrics import unidirectional_chamfer
from deepcurrents.experiments.tables import write_table
from deepcurrents.geometry.meshes import read_mesh
from deepcurrents.geometry.topology import consistently_oriented

log = logging.getLogger(__name__)


def body_extent(body: StitchedBody) -> float:
    """The largest side of the body's bounding box: UCDs divided by it are in the paper's [-0.5, 0.5]^3 units."""
    return float((body.body_vertices.max(0) - body.body_vertices.min(0)).max())


def shared_loops(body: StitchedBody) -> list[SharedLoop]:
    return [SharedLoop(name, pair, verts) for name, pair, verts, _ in body.loops]


def seam_report(stitched: StitchedMesh, loops: list[SharedLoop]) -> dict[str, dict[str, Any]]:
    """For each seam: its vertices, the largest distance of one from its loop, and whether both parts' faces use
    every one of them (the seam is identical on both sides)."""
    faces, names = np.asarray(stitched.mesh.faces), stitched.part_names
    out = {}
    for loop in loops:
        seam = stitched.seams.get(loop.name)
        if seam is None:
            out[loop.name] = {"stitched": False, "why": stitched.open_loops.get(loop.name, "")}
            continue
        _, dist = loop_parameter(np.asarray(stitched.mesh.vertices)[seam], loop.vertices)
        used = [set(np.unique(faces[stitched.face_part == names.index(p)])) for p in loop.parts]
        shared = all(set(seam.tolist()) <= u for u in used)
        out[loop.name] = {"stitched": True, "vertices": int(len(seam)), "distance_to_loop": float(dist.max()),
                          "loop_vertices": int(len(loop.vertices)), "identical_on_both_sides": bool(shared)}
    return out


def check_body(cfg) -> None:
    """``suite.check`` of experiment=stitched_body: the body folder is whole (``read_body``'s one sentence) before
    any part trains."""
    read_body(cfg.suite.body)


def stitch_report(out_dir: Path, results: list[dict[str, Any]], cfg=None) -> dict[str, Any]:
    """The suite's report (module docstring). → the stitched body's metrics."""
    out_dir = Path(out_dir)
    body = read_body(cfg.suite.body)
    extent = body_extent(body)
    loops = shared_loops(body)
    meshes, targets, rows = {}, {}, []
    for r in results:
        name, path = r["name"], Path(r.get("mesh") or Path(r["dir"]) / "mesh.ply")
        targets[name] = read_mesh(body.part_file(name), "Part mesh")
        if path.is_file():
            meshes[name] = read_mesh(path, "Part mesh")
        m = r["metrics"]
        rows.append({"part": name, "ucd": _scaled(m.get("ucd_input_units", m.get("ucd")), extent),
                     "ucd_reverse": _scaled(m.get("ucd_reverse_input_units", m.get("ucd_reverse")), extent),
                     "boundary_error": m.get("boundary_error"), "surface": m.get("surface"),
                     "train_seconds": m.get("train_seconds"), "steps": m.get("steps")})
    tolerance = 1e-5 * extent  # the parts' files and meshes are float32 PLYs: their borders lie ~1e-7 off the loops
    stitched = stitch_parts(meshes, loops, tolerance, targets)
    stitched.mesh.export(out_dir / "body.ply")
    target = trimesh.Trimesh(body.body_vertices, body.body_faces, process=False)
    samples = int(cfg.evaluation.get("ucd_samples", 100_000)) if "evaluation" in cfg else 100_000
    faces = np.asarray(stitched.mesh.faces)
    part_ucds = [r["ucd"] for r in rows if r["ucd"] is not None]
    metrics = {
        "body": str(body.folder), "parts": len(results), "parts_meshed": len(meshes),
        "surface": stitched.topology.describe() if stitched.topology else "empty",
        "border_edges": stitched.border_edges, "manifold": bool(stitched.topology and stitched.topology.manifold),
        "consistently_oriented": consistently_oriented(faces) if len(faces) else False,
        "open_loops": stitched.open_loops, "flipped_parts": stitched.flipped,
        "ucd": _scaled(unidirectional_chamfer(target, stitched.mesh, samples), extent),
        "ucd_reverse": _scaled(unidirectional_chamfer(stitched.mesh, target, samples), extent),
        "mean_part_ucd": float(np.mean(part_ucds)) if part_ucds else None,
        "body_extent": extent, "vertices": int(len(stitched.mesh.vertices)), "faces": int(len(faces)),
        "seams": seam_report(stitched, loops),
    }
    if metrics["mean_part_ucd"]:
        metrics["ucd_over_mean_part_ucd"] = metrics["ucd"] / metrics["mean_part_ucd"]
    (out_dir / "stitched.json").write_text(json.dumps(metrics, indent=2))
    whole = {"ucd": metrics["ucd"], "ucd_reverse": metrics["ucd_reverse"], "surface": metrics["surface"]}
    table = [{"name": r.pop("part"), "metrics": r} for r in rows] + [{"name": "body (stitched)", "metrics": whole}]
    write_table(out_dir, table, columns=["run", "ucd", "ucd_reverse", "boundary_error", "surface", "train_seconds",
                                         "steps"], name="stitched")
    draw_body(stitched, loops, out_dir / "body.png")
    log.info("stitched body: %s, %d border edges, UCD %.4g (reverse %.4g; the parts' mean %.4g), in the body's box "
             "scaled to 1; %s", metrics["surface"], metrics["border_edges"], metrics["ucd"], metrics["ucd_reverse"],
             metrics["mean_part_ucd"] or float("nan"), out_dir / "body.ply")
    return metrics


def _scaled(value, extent: float):
    return None if value is None else float(value) / extent


# faces drawn in body.png: the stitched mesh decimated to about this many (a random share of the faces would speckle it)
PICTURE_FACES = 60_000


def draw_body(stitched: StitchedMesh, loops: list[SharedLoop], path: Path) -> None:
    """The stitched body from the front and from the back, its seams (the shared loops) in black."""
    import gpytoolbox

    from deepcurrents.eval.plots import figure_pixels, plot_mesh
    from deepcurrents.eval.render.media import save_image

    mesh = stitched.mesh
    if len(mesh.faces) > PICTURE_FACES and stitched.topology is not None and stitched.topology.manifold:
        verts, faces, _, _ = gpytoolbox.decimate(np.asarray(mesh.vertices), np.asarray(mesh.faces),
                                                 num_faces=PICTURE_FACES)
        mesh = trimesh.Trimesh(verts, faces, process=False)
    tiles = []
    for azimuth in (-90.0, 90.0):
        fig = plot_mesh(mesh, [lp.vertices for lp in loops], elev=10.0, azim=azimuth, size=5.0)
        tiles.append(np.ascontiguousarray(figure_pixels(fig)[..., :3]))
    save_image(np.concatenate(tiles, axis=1), path)


def _member_overrides(suite_dir: Path, name: str) -> list[str]:
    """The overrides the suite's member ``name`` ran with (its suite.json)."""
    path = suite_dir / "suite.json"
    try:
        members = {str(m["name"]): [str(o) for o in m["overrides"]] for m in json.loads(path.read_text())}
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise UserInputError(f"'{path}' does not list the stitched body's parts ({type(err).__name__}).") from None
    if name not in members:
        raise UserInputError(f"'{path}' has no part {name}.")
    return members[name]


def _model_frame(ckpt: Path) -> tuple[float, np.ndarray]:
    """(scale, offset) of a reconstruction's checkpoint: model coordinates = (input − offset) / scale."""
    from deepcurrents.models.loading import read_checkpoint

    state = read_checkpoint(ckpt)["state_dict"]
    return float(state["target_scale"]), state["target_offset"].double().numpy()


def edit_body(suite_dir: str | Path, loop: str, move, out_dir: str | Path, carry: bool = True, steps: int = 300,
              jobs: int | str = "auto") -> dict[str, Any]:
    """Moves one loop of a stitched body (``data.body_edit.move_loop``), refits the deformed parts from their
    checkpoints for ``steps`` steps in their first runs' frames (``init_from``), moves the carried parts' meshes
    with the loop, and stitches the edited body into ``out_dir`` (``body.ply``, ``body.png``, ``stitched.json``, the
    edited body folder ``body/`` and ``edit.png``: before and after). → the edited body's metrics."""
    from deepcurrents.data.body_edit import move_loop
    from deepcurrents.data.body_partition import write_body_files
    from deepcurrents.experiments.run_dir import make_run_dir
    from deepcurrents.experiments.runner import run_members_in_processes, suite_jobs

    suite_dir = Path(suite_dir)
    summary_path = suite_dir / "stitched.json"
    if not summary_path.is_file():
        raise UserInputError(f"'{suite_dir}' is not a stitched body's folder (no stitched.json); run "
                             "`python train.py experiment=stitched_body` first.")
    body = read_body(json.loads(summary_path.read_text())["body"])
    verts, refit, rigid = move_loop(body, loop, move, carry)  # a bad loop or move is said before anything is written
    jobs = suite_jobs(jobs, len(refit))
    out_dir = make_run_dir(Path(out_dir))
    names = list(body.parts)
    edited = write_body_files(out_dir / "body", verts, body.body_faces, body.face_part, names,
                              {n: body.parts[n].get("parent") for n in names},
                              [(n, c, p, idx) for n, (c, p), _, idx in body.loops],
                              {"edited_from": str(body.folder), "loop": loop, "carry": carry,
                               "move": {"rotate": move.rotate, "axis": None if move.axis is None else list(move.axis),
                                        "scale": move.scale, "translate": list(move.translate)}})
    edited_body = read_body(edited)
    members, frames = {}, {}
    for name in refit:
        ckpt = suite_dir / name / "checkpoints" / "last.ckpt"
        scale, offset = frames[name] = _model_frame(ckpt)
        target = read_mesh(edited_body.part_file(name), "Part mesh")
        model_target = out_dir / "targets" / f"{name}.ply"
        model_target.parent.mkdir(parents=True, exist_ok=True)
        in_frame = (np.asarray(target.vertices) - offset) / scale
        trimesh.Trimesh(in_frame, target.faces, process=False).export(model_target)
        keep = [o for o in _member_overrides(suite_dir, name)
                if o.lstrip("+~").split("=", 1)[0] not in ("data.mesh", "data.normalize", "trainer.max_steps",
                                                            "ckpt_path", "init_from", "hydra.run.dir", "torch_threads")]
        members[name] = ([*keep, f"data.mesh={model_target}", "data.normalize=false", f"trainer.max_steps={steps}",
                          f"init_from={ckpt}"], None)
    started = time.perf_counter()
    run_members_in_processes(members, out_dir, jobs)
    refit_seconds = time.perf_counter() - started
    results = []
    old_loop = next(v for n, _, v, _ in body.loops if n == loop)
    for name in names:
        if name in refit:  # the refitted mesh, back from its run's frame
            scale, offset = frames[name]
            mesh = read_mesh(out_dir / name / "mesh.ply", "Part mesh")
            metrics = json.loads((out_dir / name / "metrics.json").read_text())
            metrics = {**metrics, **{f"{k}_input_units": metrics[k] * scale for k in ("ucd", "ucd_reverse")
                                     if k in metrics}}
            vertices = np.asarray(mesh.vertices) * scale + offset
        else:
            mesh = read_mesh(suite_dir / name / "mesh.ply", "Part mesh")
            metrics = json.loads((suite_dir / name / "metrics.json").read_text())
            vertices = move.apply(np.asarray(mesh.vertices), old_loop) if name in rigid else np.asarray(mesh.vertices)
            if name in rigid:  # distances scale with the move
                scaled = ("ucd_input_units", "ucd_reverse_input_units")
                metrics = {**metrics, **{k: metrics[k] * move.scale for k in scaled if k in metrics}}
        path = make_run_dir(out_dir / name) / "mesh_body.ply"
        trimesh.Trimesh(vertices, mesh.faces, process=False).export(path)
        results.append({"name": name, "dir": str(out_dir / name), "mesh": str(path), "metrics": metrics})
    metrics = stitch_report(out_dir, results, OmegaConf.create({"suite": {"body": str(edited)}}))
    metrics.update({"loop": loop, "carry": carry, "refit": refit, "moved_rigidly": rigid, "refit_steps": steps,
                    "refit_seconds": round(refit_seconds, 1)})
    (out_dir / "stitched.json").write_text(json.dumps(metrics, indent=2))
    _before_after(suite_dir / "body.png", out_dir / "body.png", out_dir / "edit.png")
    return metrics


def _before_after(before: Path, after: Path, path: Path) -> None:
    """The two pictures one above the other."""
    from PIL import Image

    if not before.is_file():
        return
    a, b = Image.open(before).convert("RGB"), Image.open(after).convert("RGB")
    out = Image.new("RGB", (max(a.width, b.width), a.height + b.height), "white")
    out.paste(a, (0, 0))
    out.paste(b, (0, a.height))
    out.save(path)
