"""The boundary-conditioned autodecoder as a LightningModule (paper §4.3, §5.3).

One latent code per training mesh (an ``nn.Embedding`` initialised from N(0, 0.1²)), one boundary encoder
per loop, one decoder; trained with the reconstruction losses (current loss under the metric B_x,
surface hinge loss) on augmented meshes. Under DDP the codes and encoders are ordinary parameters: each
rank trains its own shard of the meshes and gradients are averaged as for any other weight (rows of
codes a rank did not see get zero gradient there).

The unaugmented training boundaries and bounding boxes are saved in checkpoints, so one is enough to
rebuild, mesh, interpolate and edit every training shape (``deepcurrents.cli.interpolate`` / ``generate``).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from deepcurrents.data.recon import ambient_options
from deepcurrents.data.targets import SURFACE_EPSILON
from deepcurrents.errors import ConfigError, UserInputError
from deepcurrents.eval.families import (
    EvaluatedMember,
    family_metrics,
    measure_member,
    meshing_cube,
    plot_members,
    write_per_shape_table,
)
from deepcurrents.eval.meshing import extract_surface, mesh_method
from deepcurrents.eval.metrics import jump
from deepcurrents.losses import current_loss, level_loss, surface_loss, surface_values, winding_loss
from deepcurrents.models.base import DeepCurrentsModule, network_kwargs
from deepcurrents.models.family_interpolation import InterpolationRegulariser
from deepcurrents.models.latent_fit import fit_latent, latent_fit_settings
from deepcurrents.nn.family import ConditionedCurrent, FamilyCurrent

log = logging.getLogger(__name__)


# where checkpoints keep the family's unaugmented boundaries and boxes
FAMILY_KEY = "deepcurrents_family"


class CheckpointMismatchError(UserInputError):
    """A checkpoint whose family (shapes, loops) is not the one configured."""


def training_shapes(loop_lengths: Sequence[Sequence[int]], train_loops: Sequence[Sequence[np.ndarray]] | None,
                    train_bounds: Sequence[np.ndarray] | None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The family's unaugmented training boundaries, padded, and boxes (zeros where not given: a checkpoint
    fills them). → loops (S, B, L, 3), mask (S, B, L), bounds (S, 2, 3)."""
    lengths = torch.tensor(loop_lengths, dtype=torch.long)  # (S, B)
    num_shapes, num_loops = lengths.shape
    length = int(lengths.max())
    loops = torch.zeros(num_shapes, num_loops, length, 3)
    mask = torch.arange(length)[None, None] < lengths[..., None]
    bounds = torch.zeros(num_shapes, 2, 3)
    if train_loops is not None:
        for i, shape in enumerate(train_loops):
            for b, lp in enumerate(shape):
                loops[i, b, : len(lp)] = torch.as_tensor(np.asarray(lp), dtype=torch.float32)
    if train_bounds is not None:
        bounds.copy_(torch.as_tensor(np.asarray(train_bounds), dtype=torch.float32))
    return loops, mask, bounds


def check_same_family(saved: dict[str, Any], configured: dict[str, Any]) -> None:
    """CheckpointMismatchError unless a checkpoint's family (``saved``, its hyperparameters) is the configured one:
    the same loops per shape, training meshes, loop vertex counts and code sizes."""
    for key, what in (("num_loops", "boundary loops per shape"), ("num_shapes", "training shapes"),
                      ("shape_names", "training meshes"), ("loop_lengths", "boundary vertex counts"),
                      ("latent_dim", "latent size"), ("boundary_dim", "boundary code size")):
        # as nested lists: loop_lengths is (S, B), and comparing its rows as arrays is ambiguous for B ≥ 2
        if key in saved and np.asarray(saved[key]).tolist() != np.asarray(configured[key]).tolist():
            detail = f" ({saved[key]} vs {configured[key]})" if key in ("num_loops", "num_shapes") else ""
            raise CheckpointMismatchError(
                f"The checkpoint was trained on another family: its {what} differ from the "
                f"configured data's{detail}; point data.path at the checkpoint's meshes or start afresh."
            )


class AutodecoderModule(DeepCurrentsModule):
    """Families of currents: f_θ(x; z_i, Γ_i) for the training shapes i, and any (z, Γ) afterwards.

    Args:
        num_shapes, num_loops, shape_names: the family (from ``FamilyDataModule.model_kwargs``).
        net: decoder settings (width, depth, activation, alpha_scale, zero_init_output).
        rff: the decoder's random Fourier features (num_frequencies, sigma, enabled, seed).
        optim: {"lr", "step_size", "gamma", "schedule", "warmup", "min_factor", "fused"} (``DeepCurrentsModule``).
        latent_dim, boundary_dim, latent_std: sizes of z and z_Γ (paper 256, 256) and the codes' initial std.
        latent_lr_factor: the latent codes train at this multiple of ``optim.lr`` (beyond the paper, which has one
            rate; 1 = the paper). A code sees only its own shape's batches, the decoder every batch.
        surface_weight, surface_margin: weight and δ of the surface hinge loss (paper: 1, 0.01).
        mass_weight: λ of a Euclidean mass term λ E_x|ω(x)| (B = I) at the current loss's uniform samples (beyond
            the paper; 0 = the paper): the metric B_x = w_x (I − n nᵀ) leaves ω's component along n free off Σ.
        winding_weight: weight of ``losses.winding_loss`` (beyond the paper; 0 = the paper): f may drop by at most
            one full jump 4π·alpha_scale across the surface, where the hinge asks only for at least δ.
        winding_reach: the cap's offsets as a multiple r ≥ 1 of the hinge's ε (r > 1: f also at y ± rεn).
        level_weight: weight of ``losses.level_loss`` per shape (beyond the paper; 0 = the paper): f's drop straddles
            the mesher's level, each shape's the mean of f over its own loop vertices.
        interpolation_weight, interpolation_mix, interpolation_sampling: the interpolation regulariser
            (``models.family_interpolation``; weight 0 = the paper).
        latent_fit: {"steps", "lr", "num_samples", "num_surface_samples", "prior_weight"} of ``fit_latent`` for
            the shapes held out of training (``data.held_out``).
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
        latent_lr_factor: float = 1.0,
        surface_weight: float = 1.0,
        surface_margin: float = 0.01,
        mass_weight: float = 0.0,
        winding_weight: float = 0.0,
        winding_reach: float = 1.0,
        level_weight: float = 0.0,
        interpolation_weight: float = 0.0,
        interpolation_mix: str = "shared",
        interpolation_sampling: dict | None = None,
        latent_fit: dict | None = None,
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
        self.interpolation = InterpolationRegulariser(
            interpolation_mix, ambient_options(interpolation_sampling, "model.interpolation_sampling", anchors=False))
        self.save_hyperparameters(ignore=["train_loops", "train_bounds"])
        self.evaluation = dict(evaluation or {})
        self.meshing_said: set = set()  # the coarse-grid warnings given while meshing members (once each)
        self.family = FamilyCurrent(num_shapes, num_loops, latent_dim, boundary_dim, latent_std=latent_std,
                                    **network_kwargs(net, rff))
        # The unaugmented boundaries and boxes are data, not weights: plain CPU tensors saved in the
        # checkpoint by on_save_checkpoint (as buffers DDP would broadcast them at every step).
        self.train_loops, self.train_loop_mask, self.train_bounds = training_shapes(loop_lengths, train_loops,
                                                                                    train_bounds)

    def parameter_groups(self, lr: float) -> list[dict]:
        """The latent codes at ``latent_lr_factor`` × lr, everything else at lr (one group at the paper's 1)."""
        factor = float(self.hparams.latent_lr_factor)
        if factor == 1.0:
            return super().parameter_groups(lr)
        codes = self.family.latents.weight
        rest = [p for p in self.parameters() if p is not codes]
        return [{"params": rest}, {"params": [codes], "lr": lr * factor}]

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

    def meshing_bounds(self, shapes: Sequence[int], loops: Sequence[np.ndarray] = (),
                       boxes: Sequence[np.ndarray] = (), padding: float | None = None) -> np.ndarray:
        """The region to mesh (``eval.families.meshing_cube``) around the given training shapes' boxes, the loops'
        box and any further ``boxes`` (2, 3); ``padding`` None: ``evaluation.mesh.padding`` (an app's ``padding=``
        override otherwise). → (2, 3)."""
        boxes = [self.train_bounds[i].detach().cpu().double().numpy() for i in shapes] + list(boxes)
        boxes += [np.stack([lp.min(0), lp.max(0)]) for lp in loops]
        # checkpoints written before the one `evaluation` node kept the family's padding at evaluation.padding
        if padding is None:
            padding = self.evaluation.get("padding", dict(self.evaluation.get("mesh", {})).get("padding", 0.1))
        return meshing_cube(boxes, float(padding))

    def mesh_member(self, current: ConditionedCurrent, bounds: np.ndarray, resolution: int | None = None):
        """``extract_surface`` of a member with the evaluation's meshing settings in ``bounds`` (``resolution``: cells
        along the longest side instead of the evaluation's)."""
        mesh_cfg = {k: v for k, v in dict(self.evaluation.get("mesh", {})).items() if k not in ("bounds", "padding")}
        if resolution is not None:
            mesh_cfg["resolution"] = int(resolution)
        return extract_surface(current, bounds=bounds, **mesh_method(mesh_cfg, self.mesh_method),
                               resolution_key=self.MESH_RESOLUTION_KEY, said=self.meshing_said)

    def final_mesh_regions(self) -> list[np.ndarray]:
        """Each training shape's meshing region (``meshing_bounds``), as the final evaluation meshes them."""
        return [self.meshing_bounds([i]) for i in range(len(self.train_bounds))]

    # ------------------------------------------------------------------------------ unseen shapes
    def fit_latent(self, vertices: np.ndarray, faces: np.ndarray, loops: Sequence[np.ndarray],
                   **settings: Any) -> tuple[torch.Tensor, list[float]]:
        """The latent code of a shape not trained on (``models.latent_fit.fit_latent``). → (z, loss per step)."""
        return fit_latent(self, vertices, faces, loops, **settings)

    # --------------------------------------------------------------------------------------- training
    def compute_losses(self, batch: dict[str, torch.Tensor], z: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        """Current loss (metric B_x) and surface loss over a batch of S shapes × N points, the shapes' own
        Euclidean mass when ``mass_weight`` > 0, and the interpolants' mass loss when ``interpolation_weight`` > 0.

        z: (S, latent_dim) latent codes of the batch's shapes (default: the training codes of
        ``batch["index"]``; the latent fit of a held-out shape passes its own)."""
        loops, mask = batch["loops"], batch["loop_mask"]
        z = self.family.latents(batch["index"]) if z is None else z
        code = self.family.code(z, loops, mask)
        _, omega = self.family(batch["x"], code, loops, mask, create_graph=True)
        losses = {"current_loss": current_loss(omega.flatten(0, 1), batch["metric"].flatten(0, 1))}
        loss = losses["current_loss"]
        if self.hparams.mass_weight > 0:  # the samples are uniform in U: E|ω| is the mass
            losses["mass_loss"] = current_loss(omega.flatten(0, 1))
            loss = loss + self.hparams.mass_weight * losses["mass_loss"]
        if "surface_points" in batch and self.hparams.surface_weight > 0:
            f_minus, f_plus = surface_values(lambda points: self.family.f(points, code), batch)
            losses["surface_loss"] = surface_loss(f_minus, f_plus, self.hparams.surface_margin)
            loss = loss + self.hparams.surface_weight * losses["surface_loss"]
            if self.hparams.winding_weight > 0:
                reach = float(self.hparams.get("winding_reach", 1.0))  # checkpoints before the key: 1
                if reach != 1.0:
                    f_minus, f_plus = surface_values(lambda points: self.family.f(points, code),
                                                     {**batch, "epsilon": reach * batch["epsilon"]})
                losses["winding_loss"] = winding_loss(f_minus, f_plus, jump(3) * self.family.alpha_scale)
                loss = loss + self.hparams.winding_weight * losses["winding_loss"]
        if "surface_points" in batch and self.hparams.level_weight > 0:
            # each shape's own loop vertices as its Γ points (their mean, not by arc length: the loops' vertices
            # lie about evenly along them), padding masked
            losses["level_loss"] = level_loss(lambda points: self.family.f(points, code), batch, loops.flatten(1, 2),
                                              self.hparams.surface_margin / 4, boundary_mask=mask.flatten(1, 2))
            loss = loss + self.hparams.level_weight * losses["level_loss"]
        if self.hparams.interpolation_weight > 0 and self.training:
            interpolation = self.interpolation.loss(self.family, z, loops, mask, batch["x"].shape[1],
                                                    batch.get("surface_points"))
            if interpolation is not None:
                losses["interpolation_loss"] = interpolation
                loss = loss + self.hparams.interpolation_weight * interpolation
        losses["loss"] = loss
        return losses

    def training_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> torch.Tensor:
        losses = self.compute_losses(batch)
        self.check_finite(losses["loss"])
        if self.logs_this_step():
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
        check_same_family(checkpoint.get("hyper_parameters", {}), self.hparams)
        super().on_load_checkpoint(checkpoint)
        if FAMILY_KEY in checkpoint:
            family = checkpoint[FAMILY_KEY]
            self.train_loops = family["loops"].cpu().float()
            self.train_loop_mask = family["mask"].cpu().bool()
            self.train_bounds = family["bounds"].cpu().float()

    # ------------------------------------------------------------------------------------- evaluation
    def evaluate_member(self, z: torch.Tensor, loops: list[np.ndarray], bounds: np.ndarray, target, path: Path,
                        samples: int, seed: int) -> tuple[dict[str, Any], Any]:
        """Meshes the member (z, Γ) in ``bounds``, writes it to ``path`` and measures it against ``target``
        (``eval.families.measure_member``). → (row, mesh)."""
        return measure_member(self.mesh_member(self.member(z, loops), bounds), loops, target, path, samples, seed)

    @torch.no_grad()
    def final_evaluation(self, out_dir: str | Path, meshes: Sequence | None = None,
                         held_out: Sequence | None = None) -> dict[str, Any]:
        """Meshes every training shape under its own latent code and unaugmented boundary and measures it against
        its mesh (UCD, paper Tab. 1; ucd_reverse; boundary adherence); shapes held out of training
        (``data.held_out``) get their code by ``fit_latent`` (``model.latent_fit``) and are measured the same way,
        so ``ucd_held_out_mean`` beside ``ucd`` shows generalisation, not memory.

        Writes ``meshes/NNN_<name>.ply`` (held out: ``meshes/held_out_NNN_<name>.ply``), ``per_shape.csv``
        (``split`` = train or held_out), ``meshes.png`` and ``metrics.json`` (``eval.families``).
        ``meshes`` / ``held_out``: the family's ``FamilyMesh`` lists (default: the trainer's DataModule's)."""
        out_dir = Path(out_dir)
        (out_dir / "meshes").mkdir(parents=True, exist_ok=True)
        datamodule = self.trainer.datamodule if self._trainer is not None else None
        meshes = datamodule.meshes if meshes is None else meshes
        held_out = getattr(datamodule, "held_out_meshes", []) if held_out is None else held_out
        if [m.name for m in meshes] != list(self.hparams.shape_names):
            raise CheckpointMismatchError("The evaluation meshes are not the family this model was trained on.")
        self.family.eval()
        limit = self.evaluation.get("max_shapes")
        count = len(meshes) if limit is None else min(len(meshes), int(limit))
        samples = int(self.evaluation.get("ucd_samples", 100_000))
        seed = int(self.evaluation.get("seed", 12345))
        members = []
        for i, shape in enumerate(meshes[:count]):
            loops, stem, target = self.shape_loops(i), Path(shape.name).stem, shape.trimesh()
            row, mesh = self.evaluate_member(self.latent(i), loops, self.meshing_bounds([i]), target,
                                             out_dir / "meshes" / f"{i:03d}_{stem}.ply", samples, seed)
            members.append(EvaluatedMember({"index": i, "name": shape.name, "split": "train", **row,
                                            "fit_loss_start": None, "fit_loss_end": None}, mesh, loops,
                                           f"{i}: {stem}", target))
            log.info("shape %d (%s): ucd %s", i, shape.name, row["ucd"])
        fit_seconds = self._evaluate_held_out(held_out, datamodule, members, out_dir, samples, seed)
        write_per_shape_table(members, out_dir / "per_shape.csv")
        plot_members(members, count, out_dir / "meshes.png")
        # the last training step's loss; null when this process trained no step (a resumed run at its budget)
        loss = float(self.trainer.callback_metrics["train/loss"]) \
            if self._trainer is not None and "train/loss" in self.trainer.callback_metrics else None
        metrics = family_metrics(members, count, self.num_shapes, loss, fit_seconds)
        metrics.update(self.run_metrics())
        return self.write_metrics(out_dir, metrics)

    def _evaluate_held_out(self, held_out: Sequence, datamodule: Any, members: list[EvaluatedMember],
                           out_dir: Path, samples: int, seed: int) -> float:
        """Fits the latent code of each held-out shape (with the training data's sampling settings) and measures
        its member, appended to ``members``. → the seconds the fits took."""
        fit = latent_fit_settings(self.hparams.get("latent_fit"))
        fit_kwargs = {"boundary_sigma": float(getattr(datamodule, "boundary_sigma", 0.1)),
                      "boundary_weighting": bool(getattr(datamodule, "boundary_weighting", True)),
                      "metric_band": getattr(datamodule, "metric_band", None),
                      "sampling": getattr(datamodule, "sampling", None),
                      "surface_epsilon": getattr(datamodule, "surface_epsilon", SURFACE_EPSILON)}
        fit_seconds = 0.0
        for k, shape in enumerate(held_out):
            loops = shape.loop_points()
            start = time.perf_counter()
            z, history = self.fit_latent(shape.vertices, shape.faces, loops, **fit, seed=seed + k, **fit_kwargs)
            fit_seconds += time.perf_counter() - start
            stem, target = Path(shape.name).stem, shape.trimesh()
            box = np.stack([shape.vertices.min(0), shape.vertices.max(0)])
            row, mesh = self.evaluate_member(z, loops, self.meshing_bounds([], loops, [box]), target,
                                             out_dir / "meshes" / f"held_out_{k:03d}_{stem}.ply", samples, seed)
            tail = max(1, len(history) // 10)  # the loss is noisy (fresh samples): mean of the first / last tenth
            members.append(EvaluatedMember({"index": k, "name": shape.name, "split": "held_out", **row,
                                            "fit_loss_start": float(np.mean(history[:tail])),
                                            "fit_loss_end": float(np.mean(history[-tail:]))}, mesh, loops,
                                           f"held out: {stem}", target))
            log.info("held-out shape %s: ucd %s (latent fit %d steps)", shape.name, row["ucd"], len(history))
        return fit_seconds
