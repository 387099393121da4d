"""Single-surface reconstruction (paper §4.2, §5.2): a neural current whose boundary is the target's Γ,
trained with the current loss under B_x = w_x (I − n nᵀ) plus the surface hinge loss, and evaluated by
the unidirectional Chamfer distance (UCD) from the target to the extracted mesh."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch
import trimesh
from scipy.spatial import cKDTree

from deepcurrents.eval.meshing import flux_sign, region_of_interest
from deepcurrents.eval.metrics import point_mesh_distance, sample_surface, unidirectional_chamfer
from deepcurrents.eval.plots import MeshView, mesh_view, plot_mesh
from deepcurrents.geometry.meshes import write_mesh
from deepcurrents.geometry.polyline import closed_loop_segments, resample_polyline
from deepcurrents.losses import current_loss, level_loss, surface_hinge
from deepcurrents.models.current_module import CurrentModule


class TargetGeometry:
    """The target kept inside a module (as buffers, so it moves and saves with it) and its metrics helpers.

    ``spec`` from ``ReconstructionDataModule.model_kwargs()["target"]``: kind "mesh" (vertices, faces) or
    "points" (points, normals), in model coordinates; ``scale``/``offset`` map back to the input's.
    """

    @staticmethod
    def register(module: torch.nn.Module, spec: dict | None) -> None:
        spec = spec or {"kind": "none"}
        module.target_kind = spec["kind"]
        module.target_source = spec.get("source")
        if spec["kind"] == "mesh":
            a, b = spec["vertices"], spec["faces"]
        elif spec["kind"] == "points":
            a, b = spec["points"], spec["normals"]
        else:
            a, b = np.zeros((0, 3)), np.zeros((0, 3))
        module.register_buffer("target_a", torch.as_tensor(np.asarray(a), dtype=torch.float64))
        module.register_buffer("target_b", torch.as_tensor(np.asarray(b)))
        scale, offset = float(spec.get("scale", 1.0)), np.asarray(spec.get("offset", np.zeros(3)))
        module.register_buffer("target_scale", torch.tensor(scale, dtype=torch.float64))
        module.register_buffer("target_offset", torch.as_tensor(offset, dtype=torch.float64))
        module._register_load_state_dict_pre_hook(TargetGeometry._adopt_saved_target, with_module=True)

    @staticmethod
    def _adopt_saved_target(module, state_dict, prefix, *args) -> None:
        """A module rebuilt from a checkpoint's hyperparameters alone (the apps) has no target: take the
        saved one's shapes and kind (faces are integers, normals are not) before the weights are copied."""
        a, b = state_dict.get(prefix + "target_a"), state_dict.get(prefix + "target_b")
        if a is None or b is None or module.target_kind != "none" or len(a) == 0:
            return
        module.target_a = torch.empty_like(a, dtype=torch.float64)
        module.target_b = torch.empty_like(b)
        module.target_kind = "points" if b.is_floating_point() else "mesh"

    @staticmethod
    def mesh(module) -> trimesh.Trimesh | None:
        if module.target_kind != "mesh":
            return None
        return trimesh.Trimesh(module.target_a.cpu().numpy(), module.target_b.cpu().numpy().astype(np.int64),
                               process=False)

    @staticmethod
    def points(module) -> np.ndarray:
        return module.target_a.cpu().numpy()

    @staticmethod
    def frame(module) -> tuple[float, np.ndarray] | None:
        """(scale, offset) of a target that data.normalize moved, input = model · scale + offset (a shift alone
        counts); None where the model's frame is the target file's."""
        scale, offset = float(module.target_scale), module.target_offset.detach().cpu().double().numpy()
        return (scale, offset) if scale != 1.0 or np.abs(offset).max() > 0 else None

    @staticmethod
    def to_input(module, vertices: np.ndarray) -> np.ndarray:
        return vertices * float(module.target_scale) + module.target_offset.cpu().numpy()


def carries_target(module) -> bool:
    """Whether ``module`` holds a target (a reconstruction's, or the closest-point baseline's) to score against."""
    return getattr(module, "target_kind", "none") != "none" and len(module.target_a) > 0


def reconstruction_metrics(module, mesh: trimesh.Trimesh, samples: int, seed: int) -> dict[str, Any]:
    """UCD (target → mesh, ``samples`` uniform target samples; all points of a cloud), its reverse
    (mesh → target) and their mean, in model units (the paper's [-0.5, 0.5]^3); None for an empty mesh."""
    out: dict[str, Any] = {"ucd": None, "ucd_reverse": None, "chamfer": None}
    if len(mesh.faces) == 0:
        return out
    target = TargetGeometry.mesh(module)
    if target is not None:
        out["ucd"] = unidirectional_chamfer(target, mesh, samples, seed)
        out["ucd_reverse"] = unidirectional_chamfer(mesh, target, samples, seed)
        out["target_area"] = float(target.area)
    else:
        pts = TargetGeometry.points(module)
        out["ucd"] = float(point_mesh_distance(pts, mesh).mean())
        dist, _ = cKDTree(pts).query(sample_surface(mesh, samples, seed))
        out["ucd_reverse"] = float(dist.mean())
    out["chamfer"] = 0.5 * (out["ucd"] + out["ucd_reverse"])
    return out


def input_unit_distances(metrics: dict[str, Any], scale: float) -> dict[str, float]:
    """``ucd`` and ``ucd_reverse`` of ``metrics`` in the target file's units (a normalised run's model frame scaled
    back by ``scale``); {} where the mesh was empty."""
    if metrics.get("ucd") is None:
        return {}
    return {"ucd_input_units": metrics["ucd"] * scale, "ucd_reverse_input_units": metrics["ucd_reverse"] * scale}


class ReconstructionModule(CurrentModule):
    """DeepCurrents for one target surface. Training: L = L_curr(B) + surface_weight · L_surf (paper §4.2,
    the authors' weight 1); batches come from ``ReconstructionDataModule`` (metric and surface samples
    already made in the workers). Evaluation: ``CurrentModule``'s mesh of f = s, meshed over the target's
    padded bounding box, plus ``ucd``, ``ucd_reverse``, ``chamfer``, ``boundary_error`` in metrics.json;
    ``mesh.ply`` in the input's coordinates.

    Args (beyond ``CurrentModule``'s):
        target: the target geometry (from the DataModule's ``model_kwargs``); kept as buffers.
        surface_weight: weight of the surface loss (0 disables it).
        surface_margin: δ of the surface hinge loss (paper 0.01).
        mass_weight: λ of a Euclidean mass term λ E|ω| at the ambient samples (beyond the paper; 0 = the paper):
            B_x = w(I − n nᵀ) leaves ω along the closest normal free off Σ, so without it a sheet parallel to
            the target (inside a nearly closed head) costs nothing.
        level_weight: weight of ``losses.level_loss`` (beyond the paper; 0 = the paper): the drop of f straddles the
            mesher's level s within ±ε/4 of the target, by δ/4 on each side.
    """

    polishes_mesh = False  # the mesh follows a target, not least area

    def __init__(self, boundary: dict, net: dict, optim: dict, rff: dict | None = None,
                 evaluation: dict | None = None, target: dict | None = None, surface_weight: float = 1.0,
                 surface_margin: float = 0.01, grid_encoding: dict | None = None, mass_weight: float = 0.0,
                 level_weight: float = 0.0):
        super().__init__(boundary, net, optim, rff, evaluation, grid_encoding)
        self.save_hyperparameters(ignore=["target"])  # the geometry lives in buffers, not in hparams
        self.surface_weight, self.surface_margin = float(surface_weight), float(surface_margin)  # experiments.schema
        self.mass_weight, self.level_weight = float(mass_weight), float(level_weight)
        self._gamma_points: torch.Tensor | None = None
        TargetGeometry.register(self, target)

    def compute_losses(self, batch: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """{"loss", "current_loss"[, "mass_loss"][, "surface_loss"][, "level_loss"]} of one batch: L_curr(B) + λ·E|ω|
        (with ``mass_weight``) + surface_weight·L_surf + level_weight·L_level."""
        _, omega = self.current(batch["x"], create_graph=True)
        out = {"current_loss": current_loss(omega, batch.get("metric"))}
        loss = out["current_loss"]
        if self.mass_weight > 0:
            # λ E|ω| (B = I) at the same samples: the metric leaves ω along n free off Σ, so a sheet parallel
            # to the target inside a nearly closed part costs nothing without it (validate_config keeps the
            # samples uniform, so this is λ × the mass)
            out["mass_loss"] = current_loss(omega)
            loss = loss + self.mass_weight * out["mass_loss"]
        if "surface_points" in batch and self.surface_weight > 0:
            out["surface_loss"] = surface_hinge(self.current.f, batch, self.surface_margin)
            loss = loss + self.surface_weight * out["surface_loss"]
        if "surface_points" in batch and self.level_weight > 0:
            out["level_loss"] = level_loss(self.current.f, batch, self.boundary_points(), self.surface_margin / 4)
            loss = loss + self.level_weight * out["level_loss"]
        out["loss"] = loss
        return out

    def boundary_points(self, spacing: float = 0.01) -> torch.Tensor:
        """Γ resampled every ``spacing`` (P, 3), on the module's device; made once (Γ is fixed)."""
        if self._gamma_points is None or self._gamma_points.device != self.current.loops[0].device:
            starts, ends, _ = closed_loop_segments([lp.detach().cpu().double().numpy() for lp in self.current.loops])
            self._gamma_points = torch.as_tensor(resample_polyline(starts, ends, spacing), dtype=torch.float32,
                                                 device=self.current.loops[0].device)
        return self._gamma_points

    def training_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> torch.Tensor:
        losses = self.compute_losses(batch)
        loss = losses["loss"]
        self.check_finite(loss)
        if self.logs_this_step():
            self.log("train/loss", loss, prog_bar=True)
            self.log("train/current_loss", losses["current_loss"], prog_bar=True)
            for key in ("surface_loss", "mass_loss", "level_loss"):
                if key in losses:
                    self.log(f"train/{key}", losses[key])
            self.log("train/lr", self.trainer.optimizers[0].param_groups[0]["lr"])
        return loss

    mesh_method = "level_set"  # the metric leaves ω along n free off the surface (see eval.meshing.mesh_method)

    def target_bounds(self, padding: float = 0.15) -> np.ndarray | None:
        """Where a reconstruction is meshed: the target's bounding box grown by ``padding`` × its largest
        extent (Γ's box, the minimal-surface default, is too small for a surface that bulges away from its
        boundary). → (2, 3), or None without a target."""
        if not len(self.target_a):
            return None
        return region_of_interest([self.target_a.cpu().numpy()], padding)

    def picture_view(self, loops: list[np.ndarray]) -> MeshView | None:
        """``mesh.png`` and ``target.png`` share one view, framed on the target and Γ (a mesh with debris
        far from the target would otherwise zoom out, and a torn one zoom in)."""
        if not len(self.target_a):
            return None
        return mesh_view([TargetGeometry.points(self), *loops])

    def mesh_options(self) -> dict[str, Any]:
        options = super().mesh_options()
        if options.get("bounds") is None:
            options["bounds"] = self.target_bounds(options.get("padding", 0.15))
        options["closed_on"] = self.closed_pieces_on()
        return options

    def closed_pieces_on(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The target mesh (vertices, faces) on which closed pieces of the extracted mesh are kept, not dropped as
        bubbles (``extract_surface``'s ``closed_on``: a cavity pinched off by the grid); None for point clouds."""
        target = TargetGeometry.mesh(self)
        return None if target is None else (np.asarray(target.vertices), np.asarray(target.faces))

    @torch.no_grad()
    def final_evaluation(self, out_dir: str | Path) -> dict[str, Any]:
        out_dir = Path(out_dir)
        metrics = super().final_evaluation(out_dir)
        mesh = self.meshing.mesh
        samples = int(self.evaluation.get("ucd_samples", 100_000))
        seed = int(self.evaluation.get("seed", 12345))
        metrics.update(reconstruction_metrics(self, mesh, samples, seed))
        frame = TargetGeometry.frame(self)
        scale = frame[0] if frame is not None else 1.0
        if frame is not None:  # a shift alone too: every normalised run has the keys
            metrics.update(input_unit_distances(metrics, scale))
            # the mesh and Γ in the input's coordinates, so that they compare with the user's file
            write_mesh(trimesh.Trimesh(TargetGeometry.to_input(self, np.asarray(mesh.vertices)), mesh.faces,
                                       process=False), out_dir / "mesh.ply")
            metrics["mesh_area_input_units"] = float(mesh.area) * scale**2
        metrics["target"] = self.target_source
        target = TargetGeometry.mesh(self)
        if target is not None:
            # beside mesh.png: the same view, and faces oriented along the current as the extracted mesh's
            # are (ω runs against the target's Stokes normals, so its own orientation would show the
            # complementary colours, as if seen from behind)
            loops = [lp.cpu().double().numpy() for lp in self.current.loops]
            if flux_sign(self.current, np.asarray(target.vertices), np.asarray(target.faces)) < 0:
                target = trimesh.Trimesh(target.vertices, np.asarray(target.faces)[:, ::-1], process=False)
            plot_mesh(target, loops, out_dir / "target.png", title="target", view=self.picture_view(loops))
        return self.write_metrics(out_dir, metrics)
