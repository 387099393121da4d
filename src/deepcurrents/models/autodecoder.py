"""The boundary-conditioned autodecoder as a LightningModule (paper §4.3, §5.3).

One latent code per training mesh (an ``nn.Embedding`` initialised from N(0, 0.1²)), one boundary encoder
per loop, one decoder; trained with the reconstruction losses (current loss under the metric B_x,
surface hinge loss) on augmented meshes. Under DDP the codes and encoders are ordinary parameters: each
rank trains its own shard of the meshes and gradients are averaged as for any other weight (rows of
codes a rank did not see get zero gradient there).

The unaugmented training boundaries and bounding boxes are saved in checkpoints, so one is enough to
rebuild, mesh, interpolate and edit every training shape (``deepcurrents.interpolate`` / ``generate``).
"""

from __future__ import annotations

import csv
import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from deepcurrents.errors import ConfigError, UserInputError
from deepcurrents.eval.meshing import extract_surface, mesh_method
from deepcurrents.eval.metrics import mesh_summary, unidirectional_chamfer
from deepcurrents.eval.plots import plot_mesh_grid
from deepcurrents.losses import current_loss, surface_loss
from deepcurrents.models.base import DeepCurrentsModule, network_kwargs
from deepcurrents.nn.family import ConditionedCurrent, FamilyCurrent

log = logging.getLogger(__name__)


# where checkpoints keep the family's unaugmented boundaries and boxes
FAMILY_KEY = "deepcurrents_family"


class CheckpointMismatchError(UserInputError):
    """A checkpoint whose family (shapes, loops) is not the one configured."""


class AutodecoderModule(DeepCurrentsModule):
    """Families of currents: f_θ(x; z_i, Γ_i) for the training shapes i, and any (z, Γ) afterwards.

    Args:
        num_shapes, num_loops, shape_names: the family (from ``FamilyDataModule.model_kwargs``).
        net: decoder settings (width, depth, activation, alpha_scale, zero_init_output).
        rff: the decoder's random Fourier features (num_frequencies, sigma, enabled, seed).
        optim: {"lr", "step_size", "gamma"}.
        latent_dim, boundary_dim, latent_std: sizes of z and z_Γ (paper 256, 256) and the codes' initial std.
        surface_weight, surface_margin: weight and δ of the surface hinge loss (paper: 1, 0.01).
        evaluation: the run's `evaluation` node: {"mesh": extract_surface kwargs (its "padding" sizes the meshed
            cube), "ucd_samples", "seed", "max_shapes"}.
        loop_lengths: (S, B) vertex counts of the training loops (stored; sizes the buffers on reload).
        train_loops: S lists of B arrays (M, 3), the unaugmented training boundaries (not a hyperparameter;
            saved in checkpoints).
        train_bounds: S arrays (2, 3), each training mesh's bounding box (saved in checkpoints).
    """

    mesh_method = "level_set"  # trained under the reconstruction metric (see eval.meshing.mesh_method)

    def __init__(
        self,
        num_shapes: int,
        num_loops: int,
        shape_names: Sequence[str],
        net: dict,
        optim: dict,
        rff: dict | None = None,
        latent_dim: int = 256,
        boundary_dim: int = 256,
        latent_std: float = 0.1,
        surface_weight: float = 1.0,
        surface_margin: float = 0.01,
        evaluation: dict | None = None,
        loop_lengths: Sequence[Sequence[int]] | None = None,
        train_loops: Sequence[Sequence[np.ndarray]] | None = None,
        train_bounds: Sequence[np.ndarray] | None = None,
    ):
        super().__init__(optim)
        if train_loops is not None:
            loop_lengths = [[len(lp) for lp in shape] for shape in train_loops]
        if loop_lengths is None:
            raise ConfigError("The autodecoder needs its family's boundaries (train it with data=family).")
        shape_names = list(shape_names)
        if len(shape_names) != num_shapes or len(loop_lengths) != num_shapes:
            raise ConfigError(f"model.num_shapes={num_shapes} does not match the {len(shape_names)} shape names.")
        if not surface_weight >= 0:
            raise ConfigError(f"model.surface_weight={surface_weight} must be non-negative.")
        self.save_hyperparameters(ignore=["train_loops", "train_bounds"])
        self.evaluation = dict(evaluation or {})
        self.family = FamilyCurrent(num_shapes, num_loops, latent_dim, boundary_dim, latent_std=latent_std,
                                    **network_kwargs(net, rff))
        # The unaugmented boundaries and boxes are data, not weights: plain CPU tensors saved in the
        # checkpoint by on_save_checkpoint (as buffers DDP would broadcast them at every step).
        lengths = torch.tensor(loop_lengths, dtype=torch.long)  # (S, B)
        length = int(lengths.max())
        self.train_loops = torch.zeros(num_shapes, num_loops, length, 3)
        self.train_loop_mask = torch.arange(length)[None, None] < lengths[..., None]
        self.train_bounds = torch.zeros(num_shapes, 2, 3)
        if train_loops is not None:
            for i, shape in enumerate(train_loops):
                for b, lp in enumerate(shape):
                    self.train_loops[i, b, : len(lp)] = torch.as_tensor(np.asarray(lp), dtype=torch.float32)
        if train_bounds is not None:
            self.train_bounds.copy_(torch.as_tensor(np.asarray(train_bounds), dtype=torch.float32))

    # ----------------------------------------------------------------------------------------- shapes
    @property
    def num_shapes(self) -> int:
        return self.family.num_shapes

    def check_shape_index(self, index: int, name: str = "latent") -> int:
        """Raises a one-sentence ConfigError for an index that is not a training shape."""
        if isinstance(index, bool) or not isinstance(index, (int, np.integer)) or not 0 <= index < self.num_shapes:
            raise ConfigError(
                f"{name}={index!r} is not a training shape: this checkpoint has {self.num_shapes} "
                f"(indices 0 to {self.num_shapes - 1})."
            )
        return int(index)

    def shape_loops(self, index: int) -> list[np.ndarray]:
        """The unaugmented boundary of training shape ``index``: B arrays (M_b, 3) float64."""
        counts = self.train_loop_mask[index].sum(-1).tolist()
        return [self.train_loops[index, b, :n].detach().cpu().double().numpy() for b, n in enumerate(counts)]

    def latent(self, index: int) -> torch.Tensor:
        """z of training shape ``index``. → (latent_dim,)."""
        return self.family.latents.weight[index].detach()

    def member(self, z: torch.Tensor, loops: Sequence[np.ndarray]) -> ConditionedCurrent:
        """The single current with latent code z (latent_dim,) and boundary loops (B arrays (M_b, 3))."""
        if len(loops) != self.hparams.num_loops:
            raise UserInputError(
                f"The boundary has {len(loops)} loops but this family's shapes have {self.hparams.num_loops}."
            )
        return ConditionedCurrent(self.family, z, [torch.as_tensor(lp, dtype=torch.float32) for lp in loops]).eval()

    def meshing_bounds(self, shapes: Sequence[int], loops: Sequence[np.ndarray] = ()) -> np.ndarray:
        """The region to mesh: the cube around the union of the given training shapes' boxes and the loops'
        box, of side (1 + 2·``evaluation.mesh.padding``) × its largest extent, clipped to the domain. → (2, 3).

        A cube rather than the tight box: a learned (or interpolated) surface may leave the target's box,
        and a thin box would hide spurious sheets from the UCD."""
        boxes = [self.train_bounds[i].detach().cpu().double().numpy() for i in shapes]
        boxes += [np.stack([lp.min(0), lp.max(0)]) for lp in loops]
        lo = np.min([b[0] for b in boxes], 0)
        hi = np.max([b[1] for b in boxes], 0)
        # checkpoints written before the one `evaluation` node kept the family's padding at evaluation.padding
        padding = self.evaluation.get("padding", dict(self.evaluation.get("mesh", {})).get("padding", 0.1))
        half = 0.5 * (1.0 + 2.0 * float(padding)) * float((hi - lo).max()) + 1e-3
        centre = 0.5 * (lo + hi)
        return np.stack([np.maximum(centre - half, -1.0), np.minimum(centre + half, 1.0)])

    def mesh_member(self, current: ConditionedCurrent, bounds: np.ndarray):
        """``extract_surface`` of a member with the evaluation's meshing settings in ``bounds``."""
        mesh_cfg = {k: v for k, v in dict(self.evaluation.get("mesh", {})).items() if k not in ("bounds", "padding")}
        return extract_surface(current, bounds=bounds, **mesh_method(mesh_cfg, self.mesh_method))

    # --------------------------------------------------------------------------------------- training
    def compute_losses(self, batch: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """Current loss (metric B_x) and surface loss over a batch of S shapes × N points."""
        loops, mask = batch["loops"], batch["loop_mask"]
        code = self.family.code(self.family.latents(batch["index"]), loops, mask)
        _, omega = self.family(batch["x"], code, loops, mask, create_graph=True)
        losses = {"current_loss": current_loss(omega.flatten(0, 1), batch["metric"].flatten(0, 1))}
        loss = losses["current_loss"]
        if "surface_points" in batch and self.hparams.surface_weight > 0:
            offset = batch["epsilon"].unsqueeze(-1) * batch["surface_normals"]
            y = batch["surface_points"]
            f_minus, f_plus = self.family.f(torch.cat([y - offset, y + offset], 1), code).chunk(2, dim=1)
            losses["surface_loss"] = surface_loss(f_minus.flatten(), f_plus.flatten(), self.hparams.surface_margin)
            loss = loss + self.hparams.surface_weight * losses["surface_loss"]
        losses["loss"] = loss
        return losses

    def training_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> torch.Tensor:
        losses = self.compute_losses(batch)
        self.check_finite(losses["loss"])
        size = int(batch["index"].numel())
        for key, value in losses.items():
            self.log(f"train/{key}", value, prog_bar=key == "loss", batch_size=size)
        self.log("train/lr", self.trainer.optimizers[0].param_groups[0]["lr"], batch_size=size)
        return losses["loss"]

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        super().on_save_checkpoint(checkpoint)
        checkpoint[FAMILY_KEY] = {"loops": self.train_loops, "mask": self.train_loop_mask, "bounds": self.train_bounds}

    def on_load_checkpoint(self, checkpoint: dict) -> None:
        """Refuses (one sentence) a checkpoint of another family before its weights are loaded."""
        saved = checkpoint.get("hyper_parameters", {})
        for key, what in (("num_loops", "boundary loops per shape"), ("num_shapes", "training shapes"),
                          ("shape_names", "training meshes"), ("loop_lengths", "boundary vertex counts"),
                          ("latent_dim", "latent size"), ("boundary_dim", "boundary code size")):
            if key in saved and list(np.atleast_1d(saved[key])) != list(np.atleast_1d(self.hparams[key])):
                detail = f" ({saved[key]} vs {self.hparams[key]})" if key in ("num_loops", "num_shapes") else ""
                raise CheckpointMismatchError(
                    f"The checkpoint was trained on another family: its {what} differ from the "
                    f"configured data's{detail}; point data.path at the checkpoint's meshes or start afresh."
                )
        super().on_load_checkpoint(checkpoint)
        if FAMILY_KEY in checkpoint:
            family = checkpoint[FAMILY_KEY]
            self.train_loops = family["loops"].cpu().float()
            self.train_loop_mask = family["mask"].cpu().bool()
            self.train_bounds = family["bounds"].cpu().float()

    # ------------------------------------------------------------------------------------- evaluation
    @torch.no_grad()
    def final_evaluation(self, out_dir: str | Path, meshes: Sequence | None = None) -> dict[str, Any]:
        """Meshes every training shape under its own latent code and unaugmented boundary, and measures
        UCD against its mesh (paper Tab. 1's metric; ucd_reverse: mesh → target, which sees spurious
        sheets that UCD does not) and boundary adherence.

        Writes ``meshes/NNN_<name>.ply``, ``per_shape.csv``, ``meshes.png`` (up to 12 shapes) and
        ``metrics.json`` (ucd = mean over shapes, ucd_worst, boundary_error mean / worst, ...).
        ``meshes``: the family's ``FamilyMesh`` list (default: the trainer's DataModule's).
        """
        out_dir = Path(out_dir)
        (out_dir / "meshes").mkdir(parents=True, exist_ok=True)
        if meshes is None:
            meshes = self.trainer.datamodule.meshes
        names = [m.name for m in meshes]
        if names != list(self.hparams.shape_names):
            raise CheckpointMismatchError("The evaluation meshes are not the family this model was trained on.")
        self.family.eval()
        count = len(meshes)
        limit = self.evaluation.get("max_shapes")
        if limit is not None:
            count = min(count, int(limit))
        samples = int(self.evaluation.get("ucd_samples", 100_000))
        seed = int(self.evaluation.get("seed", 12345))
        rows, learned = [], []
        for i in range(count):
            loops = self.shape_loops(i)
            result = self.mesh_member(self.member(self.latent(i), loops), self.meshing_bounds([i]))
            mesh = result.mesh
            stem = Path(names[i]).stem
            mesh.export(out_dir / "meshes" / f"{i:03d}_{stem}.ply")
            empty = len(mesh.faces) == 0
            target = meshes[i].trimesh()
            summary = mesh_summary(result, loops)
            rows.append({
                "index": i, "name": names[i],
                "ucd": None if empty else unidirectional_chamfer(target, mesh, samples, seed),
                "ucd_reverse": None if empty else unidirectional_chamfer(mesh, target, samples, seed),
                "boundary_error": summary["boundary_error"], "mesh_faces": summary["mesh_faces"],
                "mesh_area": summary["mesh_area"], "target_area": float(target.area),
                "boundary_loops_closed": summary["boundary_loops_closed"],
            })
            learned.append((mesh, loops, f"{i}: {stem}"))
            log.info("shape %d (%s): ucd %s", i, names[i], rows[-1]["ucd"])
        with open(out_dir / "per_shape.csv", "w", newline="") as fh:
            writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
        shown = learned[:12]
        plot_mesh_grid([m for m, _, _ in shown], [lp for _, lp, _ in shown], out_dir / "meshes.png",
                       titles=[t for _, _, t in shown])
        ucd = [r["ucd"] for r in rows if r["ucd"] is not None]
        be = [r["boundary_error"] for r in rows if r["boundary_error"] is not None]
        metrics: dict[str, Any] = {
            "loss": float(self.trainer.callback_metrics.get("train/loss", float("nan")))
            if self._trainer is not None else None,
            "ucd": float(np.mean(ucd)) if ucd else None,
            "ucd_worst": float(np.max(ucd)) if ucd else None,
            "ucd_worst_index": int(rows[int(np.argmax([r["ucd"] if r["ucd"] is not None else -1 for r in rows]))]
                                   ["index"]) if ucd else None,
            "ucd_reverse": float(np.mean([r["ucd_reverse"] for r in rows if r["ucd_reverse"] is not None]))
            if ucd else None,
            "boundary_error": float(np.mean(be)) if be else None,
            "boundary_error_worst": float(np.max(be)) if be else None,
            "empty_meshes": sum(r["ucd"] is None for r in rows),
            "shapes_evaluated": count,
            "num_shapes": self.num_shapes,
            **self.run_metrics(),
        }
        return self.write_metrics(out_dir, metrics)

