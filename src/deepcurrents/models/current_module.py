"""The LightningModule for one current ω = ∇f_θ + α_Γ: minimal surfaces in 3D and 2D (B = I)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import torch
import trimesh

from deepcurrents.data.sampling import mesh_sampler
from deepcurrents.eval.certificate import sharpened_mass_estimate
from deepcurrents.eval.meshing import extract_curve_2d, extract_surface, mesh_method, mesh_region
from deepcurrents.eval.meshing.polish import polish_minimal_surface, polish_settings
from deepcurrents.eval.metrics import (
    boundary_error,
    curve_boundary_error,
    curve_length,
    mass_estimate,
    mass_estimate_settings,
    mass_to_area,
)
from deepcurrents.eval.plots import plot_current_2d
from deepcurrents.geometry.meshes import write_mesh
from deepcurrents.geometry.topology import SurfaceTopology, surface_topology
from deepcurrents.losses import current_loss
from deepcurrents.models.base import DeepCurrentsModule, network_kwargs
from deepcurrents.nn import neural_current


def boundary_spec(boundary) -> dict[str, Any]:
    """A plain-data description of a Boundary/PointBoundary (stored in hyperparameters and checkpoints).
    3D: loops in model coordinates, and ``scale``/``offset`` back to the input's (input = model·scale + offset)."""
    if hasattr(boundary, "loops"):
        spec = {"loops": [np.asarray(lp).tolist() for lp in boundary.loops], "name": boundary.name}
        if getattr(boundary, "normalized", False):
            spec.update(scale=float(boundary.scale), offset=np.asarray(boundary.offset, np.float64).tolist())
        return spec
    return {"poles": np.asarray(boundary.points).tolist(), "signs": np.asarray(boundary.signs).tolist(),
            "name": boundary.name}


def input_frame(boundary: dict) -> tuple[float, np.ndarray] | None:
    """(scale, offset) of a normalised curve's ``boundary_spec`` (input = model·scale + offset), else None."""
    if "scale" not in boundary and "offset" not in boundary:
        return None
    return float(boundary.get("scale", 1.0)), np.asarray(boundary.get("offset", np.zeros(3)), np.float64)


def reported_mesh_area(module, area: float) -> float:
    """An area in the model's box as a run reports its ``mesh_area`` (metrics.json, the title of mesh.png): in a
    normalised curve's units for a minimal surface, in the box for a reconstruction (whose file-unit area is
    ``mesh_area_input_units``)."""
    frame = input_frame((getattr(module, "hparams", None) or {}).get("boundary") or {})
    return area if frame is None else area * float(frame[0]) ** 2


# metrics that are lengths or areas, and their power of the scale
_LENGTH_KEYS = {"mass_area": 2, "mass_area_stderr": 2, "mass_area_lower": 2, "mass_area_mc": 2,
                "mass_area_mc_stderr": 2, "mass_area_sharpened": 2, "mass_area_sharpened_stderr": 2,
                "mesh_area": 2, "mesh_closed_area_dropped": 2, "boundary_error": 1, "mesh_area_polished": 2,
                "mesh_area_polished_error": 2, "mesh_area_extrapolated": 2, "mesh_area_extrapolated_error": 2,
                "mesh_area_smooth_curve": 2, "mesh_area_smooth_curve_error": 2, "polish_edge_length": 1,
                "boundary_error_polished": 1}


def topology_metrics(topology: SurfaceTopology | None) -> dict[str, Any]:
    """The surface's topology as metrics: ``surface`` in words, its genus, border loops, Euler characteristic and
    pieces."""
    if topology is None:
        return {}
    return {"surface": topology.describe(), "surface_genus": topology.genus,
            "surface_border_loops": topology.border_loops,
            "surface_euler_characteristic": topology.euler_characteristic, "surface_components": topology.components}


def input_mesh(mesh: trimesh.Trimesh, frame: tuple[float, np.ndarray]) -> trimesh.Trimesh:
    """A mesh in model coordinates moved to the input's (``input_frame``), e.g. for mesh.ply."""
    return trimesh.Trimesh(np.asarray(mesh.vertices) * frame[0] + frame[1], mesh.faces, process=False)


def metrics_in_input_units(metrics: dict[str, Any], scale: float, offset: np.ndarray) -> dict[str, Any]:
    """A normalised curve's metrics in the input's units: each area/length key (mesh_area, mass_area, ...)
    is rewritten in input units and its model-unit value kept as ``<key>_normalized``; the map is recorded
    as ``normalization_scale`` and ``normalization_offset``. The optimisation ``loss`` stays as it is."""
    out = dict(metrics)
    for key, power in _LENGTH_KEYS.items():
        if out.get(key) is not None:
            out[f"{key}_normalized"] = out[key]
            out[key] = out[key] * scale**power
    out["normalization_scale"] = scale
    out["normalization_offset"] = [float(v) for v in offset]
    return out


class CurrentModule(DeepCurrentsModule):
    """Minimal surfaces (paper §5.1) and 2D curves (Fig. 3b): minimise E|ω| over uniform samples of U.

    Args:
        boundary: ``boundary_spec`` of Γ: {"loops": [...]} in 3D or {"poles", "signs"} in 2D.
        net: the MLP and ω's normalisation (width, depth, activation, alpha_scale, zero_init_output).
        rff: the random Fourier features (num_frequencies, sigma, enabled, seed).
        grid_encoding: learned multiresolution grid features beside them (``nn.MultiresGrid``; levels 0: off).
        optim: {"lr", "step_size", "gamma"} — Adam with lr × gamma every step_size steps.
        evaluation: {"mass_samples", "mesh": {...extract_surface kwargs}, "curve": {...}}.
    """

    # the final mesh is a minimal surface, which evaluation.mesh.polish finishes (a reconstruction's is not)
    polishes_mesh = True

    def __init__(self, boundary: dict, net: dict, optim: dict, rff: dict | None = None,
                 evaluation: dict | None = None, grid_encoding: dict | None = None):
        super().__init__(optim)
        self.save_hyperparameters()
        self.evaluation = dict(evaluation or {})
        net = network_kwargs(net, rff, grid_encoding)
        self.grid_lr_factor = float((grid_encoding or {}).get("lr_factor", 1.0))
        if "loops" in boundary:
            self.current = neural_current(dim=3, loops=[torch.tensor(lp) for lp in boundary["loops"]], **net)
        else:
            self.current = neural_current(dim=2, poles=torch.tensor(boundary["poles"]),
                                         signs=torch.tensor(boundary["signs"]), **net)

    def parameter_groups(self, lr: float) -> list[dict]:
        """The grid table at ``grid_encoding.lr_factor`` × lr (a table entry is only trained by the few samples
        in its cells, so it learns from fewer, sparser gradients than the MLP's weights)."""
        grid = self.current.grid
        if grid is None:
            return super().parameter_groups(lr)
        table = {id(p) for p in grid.parameters()}
        rest = [p for p in self.parameters() if id(p) not in table]
        return [{"params": rest}, {"params": list(grid.parameters()), "lr": lr * self.grid_lr_factor}]

    @property
    def dim(self) -> int:
        return self.current.dim

    def compute_losses(self, batch: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """{"loss"}: the mass E|B ω| of one batch (importance weights and precomputed α where the batch has them)."""
        _, omega = self.current(batch["x"], create_graph=True, alpha=batch.get("alpha"))
        return {"loss": current_loss(omega, batch.get("metric"), batch.get("weight"))}

    def training_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> torch.Tensor:
        loss = self.compute_losses(batch)["loss"]
        self.check_finite(loss)
        if self.logs_this_step():
            self.log("train/loss", loss, prog_bar=True)
            # the extraction-free area (length in 2D) bound, from this batch; an upper bound only for B = I
            mass_name = "train/mass_area" if self.dim == 3 else "train/mass_length"
            self.log(mass_name, mass_to_area(float(loss.detach()), self.dim, self.current.alpha_scale), prog_bar=True)
            self.log("train/lr", self.trainer.optimizers[0].param_groups[0]["lr"])
        return loss

    @torch.no_grad()
    def final_evaluation(self, out_dir: str | Path) -> dict[str, Any]:
        """Metrics, mesh (3D) or curve (2D) and a picture, written into ``out_dir``. → metrics dict."""
        out_dir = Path(out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        self.current.eval()
        # the mesh first (3D): with evaluation.mass_refine_mesh the mass estimate refines the cells it crosses
        result = (extract_surface(self.current, **self.mesh_options(), resolution_key=self.MESH_RESOLUTION_KEY)
                  if self.dim == 3 else None)
        used: dict[str, int] = {}
        mass, stderr = mass_estimate(self.current, seed=int(self.evaluation.get("seed", 12345)), info=used,
                                     **mass_estimate_settings(self.evaluation, result.mesh if result else None))
        scale = mass_to_area(1.0, self.dim, self.current.alpha_scale)
        metrics: dict[str, Any] = {"loss": mass, **self.run_metrics(), "mass_samples": used["samples"],
                                   "mass_evaluations": used["evaluations"]}
        name = "area" if self.dim == 3 else "length"
        metrics[f"mass_{name}"] = mass * scale
        metrics[f"mass_{name}_stderr"] = stderr * scale
        if result is not None:
            self.meshing = result  # subclasses evaluate the same mesh further
            loops = [lp.cpu().double().numpy() for lp in self.current.loops]
            frame = input_frame(self.hparams.boundary)
            # mesh.ply in the input's coordinates, its border on the user's curve
            export = input_mesh(result.mesh, frame) if frame is not None else None
            title = f"{self.hparams.boundary.get('name', '')}: area {reported_mesh_area(self, result.mesh.area):.4g}"
            metrics.update(self.write_mesh(out_dir, result, loops, title, export=export))
            metrics.update(self.sharpened_bound(result))
            metrics.update(self.polished_mesh(out_dir, result.mesh, frame))
            if frame is not None:
                metrics = metrics_in_input_units(metrics, *frame)
        else:
            curves = extract_curve_2d(self.current, **self.evaluation.get("curve", {}))
            metrics["curve_length"] = curve_length(curves)
            metrics["boundary_error"] = curve_boundary_error(curves, self.current.poles.cpu().double().numpy())
            np.savez(out_dir / "curve.npz", *curves)
            self._plot_2d(curves, out_dir / "current.png")
        return self.write_metrics(out_dir, metrics)

    def sharpened_bound(self, result) -> dict[str, Any]:
        """``mass_area_sharpened``: the mass bound of the current concentrated onto its meshed phase level
        (``eval.certificate``; again an upper bound of the minimal area), for phase meshes of a Euclidean
        current. ``evaluation.sharpened``: {kappa, samples}; samples 0 skips it."""
        opts = dict(self.evaluation.get("sharpened") or {})
        samples = int(opts.get("samples", 1 << 17))
        if samples <= 0 or self.mesh_options().get("method") != "phase" or len(result.mesh.faces) == 0:
            return {}
        kappa = float(opts.get("kappa", 16.0))
        seed = int(self.evaluation.get("seed", 12345))
        # the tube about Γ integrated apart as the plain bound's is (a checkpoint from before the key: none)
        bound, stderr = sharpened_mass_estimate(self.current, mesh_sampler(result.mesh, seed=seed),
                                                result.level + math.pi, kappa=kappa, num_samples=samples, seed=seed,
                                                tube_radius=float(self.evaluation.get("mass_tube_radius") or 0.0))
        return {"mass_area_sharpened": bound, "mass_area_sharpened_stderr": stderr, "sharpened_kappa": kappa}

    def polished_mesh(self, out_dir: Path, mesh: trimesh.Trimesh, frame: tuple[float, np.ndarray] | None
                      ) -> dict[str, Any]:
        """``mesh_polished.ply`` (in the input's coordinates where ``frame`` is given) and its areas: the extracted
        mesh moved by the area flow of ``eval.meshing.polish`` with Γ (float64, as the run read it) fixed, when
        ``evaluation.mesh.polish.enabled``; the surface's topology always. Areas in model units here."""
        settings = polish_settings(self.evaluation.get("mesh"))
        loops = self.boundary_loops()
        if settings is None or not self.polishes_mesh or len(mesh.faces) == 0:
            return topology_metrics(surface_topology(mesh.faces)) if len(mesh.faces) else {}
        polished = polish_minimal_surface(mesh, loops, settings)
        metrics = {**topology_metrics(polished.topology), "polish_seconds": round(polished.seconds, 3),
                   "polish_holes_filled": polished.holes_filled, "polish_stopped": polished.stopped}
        if polished.stopped is not None:
            return metrics
        write_mesh(input_mesh(polished.mesh, frame) if frame is not None else polished.mesh,
                   out_dir / "mesh_polished.ply")
        return {**metrics, "mesh_area_polished": polished.area, "mesh_area_polished_error": polished.area_error,
                "mesh_area_extrapolated": polished.extrapolated,
                "mesh_area_extrapolated_error": polished.extrapolated_error,
                "mesh_area_smooth_curve": polished.curve_extrapolated,
                "mesh_area_smooth_curve_error": polished.curve_extrapolated_error,
                "mesh_faces_polished": int(len(polished.mesh.faces)), "polish_edge_length": polished.edge_lengths[-1],
                "polish_iterations": polished.iterations,
                "boundary_error_polished": boundary_error(polished.mesh, loops)}

    def boundary_loops(self) -> list[np.ndarray]:
        """Γ in model units as float64 (M_i, 3) arrays: as the run read it where the hyperparameters hold it (the
        current's buffers are float32)."""
        spec = (getattr(self, "hparams", None) or {}).get("boundary") or {}
        if spec.get("loops") is not None:
            return [np.asarray(lp, np.float64) for lp in spec["loops"]]
        return [lp.detach().cpu().double().numpy() for lp in self.current.loops]

    def summary(self, metrics: dict[str, Any]) -> str | None:
        """One sentence on the surface found (3D): its area (polished, extrapolated, with its estimated error, else
        the plain mesh's), the extraction-free mass bound and its topology, in the run's reported units."""
        if self.dim != 3 or metrics.get("mesh_area") is None:
            return None
        m = metrics
        found = [f"extracted mesh {m['mesh_area']:.5g}"]
        if m.get("mesh_area_polished") is not None:
            found.insert(0, f"polished mesh {m['mesh_area_polished']:.7g}")
        if m.get("mesh_area_extrapolated") is not None:
            found.insert(0, f"{m['mesh_area_extrapolated']:.7g} ± {m['mesh_area_extrapolated_error']:.1e} for Γ's "
                            "polyline")
        if m.get("mesh_area_smooth_curve") is not None:
            area = (f"minimal area {m['mesh_area_smooth_curve']:.7g} ± {m['mesh_area_smooth_curve_error']:.1e} for the "
                    f"smooth curve Γ samples ({', '.join(found)})")
        else:
            area = f"area {found[0]} ({', '.join(found[1:])})" if len(found) > 1 else f"area of the {found[0]}"
        bound = (f", mass bound {metrics['mass_area']:.4g} ± {metrics['mass_area_stderr']:.1g}"
                 if metrics.get("mass_area") is not None else "")
        surface = f"; the surface is {metrics['surface']}" if metrics.get("surface") else ""
        return f"{self.hparams.boundary.get('name') or 'Minimal surface'}: {area}{bound}{surface}."

    def mesh_options(self) -> dict[str, Any]:
        """Keyword arguments of ``extract_surface`` for the final mesh (reconstruction adds ``bounds``)."""
        return mesh_method(self.evaluation.get("mesh", {}), self.mesh_method)

    def final_mesh_regions(self) -> list[np.ndarray]:
        """The region the final mesh covers (3D; ``meshing.mesh_region`` of ``mesh_options``)."""
        if self.dim != 3:
            return []
        return [mesh_region([lp.detach().cpu().double().numpy() for lp in self.current.loops], self.mesh_options())]

    def _plot_2d(self, curves, path: Path) -> None:
        dev = next(self.parameters()).device
        g = torch.linspace(-1, 1, 201, device=dev)
        grid = torch.stack(torch.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
        f = self.current.evaluate(grid, omega=False).reshape(201, 201).cpu().numpy()
        c = torch.linspace(-0.95, 0.95, 21, device=dev)
        coarse = torch.stack(torch.meshgrid(c, c, indexing="ij"), -1).reshape(-1, 2)
        alpha = self.current.alpha(coarse).reshape(21, 21, 2).cpu().numpy()
        plot_current_2d(f, alpha, curves, self.current.poles.cpu().numpy(), self.current.signs.cpu().numpy(),
                        path, title=f"length {curve_length(curves):.4f}")
