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

import csv
import logging
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from deepcurrents.data.family import collate_shapes
from deepcurrents.data.recon import ambient_options, ambient_sampler
from deepcurrents.data.sampling import NearTargetSampler
from deepcurrents.data.targets import SURFACE_EPSILON, MeshTarget, target_sample
from deepcurrents.errors import ConfigError, UserInputError, number_at_least, positive_int
from deepcurrents.eval.meshing import extract_surface, mesh_method
from deepcurrents.eval.metrics import jump, mesh_summary, unidirectional_chamfer
from deepcurrents.eval.plots import plot_mesh_pairs
from deepcurrents.geometry.meshes import write_mesh
from deepcurrents.losses import current_loss, level_loss, surface_loss, surface_values, winding_loss
from deepcurrents.models.base import DeepCurrentsModule, network_kwargs
from deepcurrents.nn.family import ConditionedCurrent, FamilyCurrent

log = logging.getLogger(__name__)


# where checkpoints keep the family's unaugmented boundaries and boxes
FAMILY_KEY = "deepcurrents_family"


# how the interpolation regulariser blends a pair's latent codes and boundaries (see AutodecoderModule)
INTERPOLATION_MIXES = ("shared", "independent")


class CheckpointMismatchError(UserInputError):
    """A checkpoint whose family (shapes, loops) is not the one configured."""


LATENT_FIT_DEFAULTS = {"steps": 300, "lr": 1e-2, "num_samples": 2000, "num_surface_samples": 2000, "prior_weight": 0.0}


def latent_fit_settings(latent_fit: dict | None) -> dict[str, Any]:
    """``model.latent_fit`` with its defaults filled in: the keyword arguments of ``fit_latent``'s settings."""
    return {**LATENT_FIT_DEFAULTS, **dict(latent_fit or {})}


def check_latent_fit(steps: Any, lr: Any, num_samples: Any, num_surface_samples: Any, prior_weight: Any) -> int:
    """One sentence naming the ``model.latent_fit`` setting that is wrong (ConfigError), else the step count."""
    positive_int("model.latent_fit.num_samples", num_samples)
    positive_int("model.latent_fit.num_surface_samples", num_surface_samples)
    number_at_least("model.latent_fit.lr", lr, strict=True)
    number_at_least("model.latent_fit.prior_weight", prior_weight)
    return positive_int("model.latent_fit.steps", steps)


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
        mass_weight: λ of a Euclidean mass term on the training shapes, λ E_x|ω(x)| (B = I) at the same uniform
            samples as the current loss (beyond the paper; 0 = the paper). The reconstruction metric
            B_x = w_x (I − n nᵀ) leaves ω's component along the closest target normal free everywhere off Σ,
            so a current may keep mass there that costs nothing; this makes it cost. (On the CPU hands it did
            not remove the dome that the surface hinge leaves inside each hand; ``surface_margin`` did: README.)
        winding_weight: weight of ``losses.winding_loss`` at the surface samples (beyond the paper; 0 = the paper):
            f may drop by at most one full jump 4π·alpha_scale between y − εn and y + εn. The surface hinge asks
            only for at least δ, and a smooth decoder meets it with a dome that overshoots (the phase winds again
            along n, which the metric w(I − n nᵀ) does not see): the fog of the family's members (README).
        winding_reach: the cap's offsets as a multiple r ≥ 1 of the hinge's ε: 1 reads the hinge's own f(y ± εn);
            r > 1 evaluates f at y ± rεn as well (one more pass over the surface samples, f only), so a dome that
            overshoots beyond ε is capped too. Where a part is thinner than 2rε the offsets reach its far side,
            whose opposite step lowers the drop: the cap is looser there, never tighter than one jump.
        interpolation_weight: weight of the mass loss (Euclidean metric, B = I) of random interpolants between
            the batch's shapes (latent codes and boundaries blended per pair), so what lies between training
            shapes is itself a near-minimal current (beyond the paper; 0 = the paper).
        interpolation_mix: how a pair's code and boundary are blended: "shared" (one t ~ U[0, 1] for both, the
            diagonal of an interpolation grid) or "independent" (t_z, t_Γ ~ U[0, 1] apart, so the code of one
            shape with the boundary of another, the grid's off-diagonal members, is regularised too).
        interpolation_sampling: where that mass loss takes its points: {"kind": "uniform"} (U, the default) or
            {"kind": "near", "near_sigma": σ, "uniform_fraction": u}: a share u uniform in U and the rest from
            Gaussians of σ around the batch's surface samples of the pair's two shapes, with the importance
            weights 1/q that keep the loss an unbiased estimate of the mass (``data.sampling.NearTargetSampler``).
            A hand fills ~0.1 % of U, so uniform points almost never fall where an interpolant's fog lies.
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
        for key, value in (("surface_weight", surface_weight), ("interpolation_weight", interpolation_weight),
                           ("mass_weight", mass_weight), ("winding_weight", winding_weight),
                           ("level_weight", level_weight),
                           ("latent_std", latent_std)):  # 0: every code starts at the origin
            number_at_least(f"model.{key}", value)
        number_at_least("model.latent_lr_factor", latent_lr_factor, strict=True)
        number_at_least("model.winding_reach", winding_reach, 1.0)  # a multiple of the surface loss's ε
        check_latent_fit(**latent_fit_settings(latent_fit))  # refused before training, not at its end
        if interpolation_mix not in INTERPOLATION_MIXES:
            raise ConfigError(f"model.interpolation_mix='{interpolation_mix}' must be one of "
                              f"{', '.join(INTERPOLATION_MIXES)}.")
        self.interpolation_sampling = ambient_options(interpolation_sampling, "model.interpolation_sampling",
                                                      anchors=False)
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
        """The region to mesh: the cube around the union of the given training shapes' boxes, the loops'
        box and any further ``boxes`` (2, 3), of side
        (1 + 2·padding) × its largest extent, clipped to the domain; ``padding`` None: ``evaluation.mesh.padding``
        (an app's ``padding=`` override otherwise). → (2, 3).

        A cube rather than the tight box: a learned (or interpolated) surface may leave the target's box,
        and a thin box would hide spurious sheets from the UCD."""
        boxes = [self.train_bounds[i].detach().cpu().double().numpy() for i in shapes] + list(boxes)
        boxes += [np.stack([lp.min(0), lp.max(0)]) for lp in loops]
        lo = np.min([b[0] for b in boxes], 0)
        hi = np.max([b[1] for b in boxes], 0)
        # checkpoints written before the one `evaluation` node kept the family's padding at evaluation.padding
        if padding is None:
            padding = self.evaluation.get("padding", dict(self.evaluation.get("mesh", {})).get("padding", 0.1))
        half = 0.5 * (1.0 + 2.0 * float(padding)) * float((hi - lo).max()) + 1e-3
        centre = 0.5 * (lo + hi)
        return np.stack([np.maximum(centre - half, -1.0), np.minimum(centre + half, 1.0)])

    def mesh_member(self, current: ConditionedCurrent, bounds: np.ndarray):
        """``extract_surface`` of a member with the evaluation's meshing settings in ``bounds``."""
        mesh_cfg = {k: v for k, v in dict(self.evaluation.get("mesh", {})).items() if k not in ("bounds", "padding")}
        return extract_surface(current, bounds=bounds, **mesh_method(mesh_cfg, self.mesh_method),
                               resolution_key=self.MESH_RESOLUTION_KEY)

    def final_mesh_regions(self) -> list[np.ndarray]:
        """Each training shape's meshing region (``meshing_bounds``), as the final evaluation meshes them."""
        return [self.meshing_bounds([i]) for i in range(len(self.train_bounds))]

    # ------------------------------------------------------------------------------ unseen shapes
    def fit_latent(self, vertices: np.ndarray, faces: np.ndarray, loops: Sequence[np.ndarray], steps: int = 300,
                   lr: float = 1e-2, num_samples: int = 2000, num_surface_samples: int = 2000,
                   boundary_sigma: float = 0.1, boundary_weighting: bool = True, seed: int = 0,
                   metric_band: float | None = None, sampling: dict | None = None,
                   surface_epsilon: float | tuple[float, float] = SURFACE_EPSILON,
                   prior_weight: float = 0.0) -> tuple[torch.Tensor, list[float]]:
        """The autodecoder's test-time step: the latent code of a shape not trained on, by Adam on z alone
        with the training losses (current loss under B_x and surface loss on the unaugmented mesh, fresh
        samples every step); the decoder, the encoders and the training codes stay frozen. z starts at
        the mean training code μ. ``prior_weight`` w > 0 adds w·|z − μ|²/s², s² the training codes' mean
        squared distance from μ (a Gaussian prior on codes, as DeepSDF's test-time fit): the decoder has
        seen nothing far from its codes, and a code that wanders there can fit the losses with a wrong shape.

        vertices (V, 3), faces (F, 3): the shape; loops: its B loops (M_b, 3) in the family's loop order.
        → (z (latent_dim,), the loss at each step (S,))."""
        steps = check_latent_fit(steps, lr, num_samples, num_surface_samples, prior_weight)
        prior_weight = float(prior_weight)
        loops = [np.asarray(lp, np.float64) for lp in loops]
        target = MeshTarget(vertices, faces, loops)
        ambient = ambient_sampler(target, ambient_options(sampling), seed=int(seed))
        gen = torch.Generator().manual_seed(int(seed))
        weight = self.family.latents.weight
        mean = weight.detach().mean(0, keepdim=True)  # (1, latent_dim)
        spread = float(((weight.detach() - mean) ** 2).sum(1).mean()) or 1.0  # s²; one training code: 1
        z = mean.clone().requires_grad_(True)
        opt = torch.optim.Adam([z], lr=float(lr))
        frozen = [(q, q.requires_grad) for q in self.family.parameters()]
        was_training, history = self.training, []
        try:
            for q, _ in frozen:
                q.requires_grad_(False)
            self.eval()  # the plain losses: no interpolation term
            with torch.enable_grad():
                for _ in range(steps):
                    item = target_sample(target, num_samples, num_surface_samples, gen, boundary_sigma=boundary_sigma,
                                         boundary_weighting=boundary_weighting, surface_loss=True,
                                         metric_band=metric_band, ambient=ambient, surface_epsilon=surface_epsilon)
                    item["index"], item["loops"] = 0, loops
                    batch = {k: v.to(weight.device) for k, v in collate_shapes([item]).items()}
                    loss = self.compute_losses(batch, z)["loss"]
                    prior = prior_weight * ((z - mean) ** 2).sum() / spread if prior_weight > 0 else 0.0
                    opt.zero_grad(set_to_none=True)
                    (loss + prior).backward()
                    opt.step()
                    history.append(float(loss.detach()))  # the training losses alone, as without a prior
        finally:
            for q, flag in frozen:
                q.requires_grad_(flag)
            self.train(was_training)
        return z.detach()[0], history

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
            interpolation = self.interpolation_loss(z, loops, mask, batch["x"].shape[1],
                                                    batch.get("surface_points"))
            if interpolation is not None:
                losses["interpolation_loss"] = interpolation
                loss = loss + self.hparams.interpolation_weight * interpolation
        losses["loss"] = loss
        return losses

    def interpolation_loss(self, z: torch.Tensor, loops: torch.Tensor, mask: torch.Tensor, num_points: int,
                           surface_points: torch.Tensor | None = None) -> torch.Tensor | None:
        """E_x |ω_t(x)| (B = I) of interpolants between each shape of the batch and the next one (a cyclic
        shift; batches come in random order, so every pair turns up): z_t = (1 − t) z_i + t z_j,
        Γ_s = (1 − s) Γ_i + s Γ_j vertex by vertex, with s = t ~ U[0, 1] per pair (``interpolation_mix`` =
        "shared") or s, t ~ U[0, 1] drawn apart ("independent": the code of one shape with the boundary of
        another, as off the diagonal of an interpolation grid). Pairs whose loops differ in vertex counts are
        skipped (None if none is left). x ~ U([-1, 1]^3), or (``interpolation_sampling.kind`` = "near") the
        importance-weighted mixture of U and Gaussians around ``surface_points`` of shapes i and j, whose
        weighted mean is the same expectation.

        z (S, latent_dim), loops (S, B, L, 3), mask (S, B, L), surface_points (S, M, 3) → scalar."""
        other = torch.roll(torch.arange(len(z), device=z.device), -1)
        same = (mask == mask[other]).flatten(1).all(1) & (other != torch.arange(len(z), device=z.device))
        if not bool(same.any()):
            return None
        i, j = same.nonzero().squeeze(1), other[same]
        t = torch.rand(len(i), 1, device=z.device, dtype=z.dtype)
        s = torch.rand(len(i), 1, device=z.device, dtype=z.dtype) \
            if self.hparams.interpolation_mix == "independent" else t
        z_t = (1 - t) * z[i] + t * z[j]
        loops_t = (1 - s[:, :, None, None]) * loops[i] + s[:, :, None, None] * loops[j]
        code = self.family.code(z_t, loops_t, mask[i])
        x, weight = self.interpolation_points(i, j, num_points, surface_points, loops.dtype)
        _, omega = self.family(x, code, loops_t, mask[i], create_graph=True)
        return current_loss(omega.flatten(0, 1), weight=None if weight is None else weight.flatten())

    def interpolation_points(self, i: torch.Tensor, j: torch.Tensor, num_points: int,
                             surface_points: torch.Tensor | None,
                             dtype: torch.dtype) -> tuple[torch.Tensor, torch.Tensor | None]:
        """The interpolation regulariser's points for pairs (i, j) and their importance weights (None: uniform).

        → x (P, num_points, 3), weight (P, num_points) or None."""
        device = i.device
        sampling = self.interpolation_sampling
        if sampling["kind"] == "uniform" or surface_points is None:
            return torch.rand(len(i), num_points, 3, device=device, dtype=dtype) * 2 - 1, None
        # NearTargetSampler per pair (numpy, on the CPU: a few thousand anchors), its stream seeded from torch's
        # so that runs stay reproducible under the run's seed
        anchors = torch.cat([surface_points[i], surface_points[j]], 1).detach().double().cpu().numpy()
        xs, weights = [], []
        for pair in anchors:
            sampler = NearTargetSampler(pair, float(sampling["near_sigma"]), float(sampling["uniform_fraction"]),
                                        weighted=bool(sampling["weighted"]))
            generator = torch.Generator().manual_seed(int(torch.randint(2**62, (1,))))
            x, w = sampler.sample(num_points, generator)
            xs.append(x)
            weights.append(w)
        return (torch.stack(xs).to(device=device, dtype=dtype),
                torch.stack(weights).to(device=device, dtype=dtype))

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
        saved = checkpoint.get("hyper_parameters", {})
        for key, what in (("num_loops", "boundary loops per shape"), ("num_shapes", "training shapes"),
                          ("shape_names", "training meshes"), ("loop_lengths", "boundary vertex counts"),
                          ("latent_dim", "latent size"), ("boundary_dim", "boundary code size")):
            # as nested lists: loop_lengths is (S, B), and comparing its rows as arrays is ambiguous for B ≥ 2
            if key in saved and np.asarray(saved[key]).tolist() != np.asarray(self.hparams[key]).tolist():
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
    def evaluate_member(self, z: torch.Tensor, loops: list[np.ndarray], bounds: np.ndarray, target, path: Path,
                        samples: int, seed: int) -> tuple[dict[str, Any], Any]:
        """Meshes the member (z, Γ) in ``bounds``, writes it to ``path`` and measures it against ``target``
        (trimesh): UCD (target → mesh, paper Tab. 1), ucd_reverse (mesh → target, which sees spurious
        sheets), boundary adherence, areas. → (row, mesh)."""
        result = self.mesh_member(self.member(z, loops), bounds)
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

    @torch.no_grad()
    def final_evaluation(self, out_dir: str | Path, meshes: Sequence | None = None,
                         held_out: Sequence | None = None) -> dict[str, Any]:
        """Meshes every training shape under its own latent code and unaugmented boundary, and measures
        UCD against its mesh (paper Tab. 1's metric; ucd_reverse: mesh → target, which sees spurious
        sheets that UCD does not) and boundary adherence. Shapes held out of training (``data.held_out``)
        get their latent code by ``fit_latent`` (``model.latent_fit``) and are measured the same way:
        ``ucd_held_out_mean`` beside ``ucd`` shows generalisation, not memory.

        Writes ``meshes/NNN_<name>.ply`` (held out: ``meshes/held_out_NNN_<name>.ply``), ``per_shape.csv``
        (``split`` = train or held_out), ``meshes.png`` (up to 12 shapes, each above its target) and
        ``metrics.json`` (ucd = mean over training shapes, ucd_worst, boundary_error mean / worst,
        ucd_held_out_mean, ...).
        ``meshes`` / ``held_out``: the family's ``FamilyMesh`` lists (default: the trainer's DataModule's).
        """
        out_dir = Path(out_dir)
        (out_dir / "meshes").mkdir(parents=True, exist_ok=True)
        datamodule = self.trainer.datamodule if self._trainer is not None else None
        if meshes is None:
            meshes = datamodule.meshes
        if held_out is None:
            held_out = getattr(datamodule, "held_out_meshes", [])
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
            stem = Path(names[i]).stem
            target = meshes[i].trimesh()
            row, mesh = self.evaluate_member(self.latent(i), loops, self.meshing_bounds([i]), target,
                                             out_dir / "meshes" / f"{i:03d}_{stem}.ply", samples, seed)
            rows.append({"index": i, "name": names[i], "split": "train", **row, "fit_loss_start": None,
                         "fit_loss_end": None})
            learned.append((mesh, loops, f"{i}: {stem}", target))
            log.info("shape %d (%s): ucd %s", i, names[i], row["ucd"])
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
            stem = Path(shape.name).stem
            box = np.stack([shape.vertices.min(0), shape.vertices.max(0)])
            target = shape.trimesh()
            row, mesh = self.evaluate_member(z, loops, self.meshing_bounds([], loops, [box]), target,
                                             out_dir / "meshes" / f"held_out_{k:03d}_{stem}.ply", samples, seed)
            tail = max(1, len(history) // 10)  # the loss is noisy (fresh samples): mean of the first / last tenth
            rows.append({"index": k, "name": shape.name, "split": "held_out", **row,
                         "fit_loss_start": float(np.mean(history[:tail])),
                         "fit_loss_end": float(np.mean(history[-tail:]))})
            learned.append((mesh, loops, f"held out: {stem}", target))
            log.info("held-out shape %s: ucd %s (latent fit %d steps)", shape.name, row["ucd"], len(history))
        with open(out_dir / "per_shape.csv", "w", newline="") as fh:
            writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
        keep_held = min(len(learned) - count, 4)  # up to 12 shapes, each above its target, up to 4 held out
        shown = learned[:count][:12 - keep_held] + learned[count:count + keep_held]
        plot_mesh_pairs([m for m, _, _, _ in shown], [t for _, _, _, t in shown], [lp for _, lp, _, _ in shown],
                        out_dir / "meshes.png", titles=[t for _, _, t, _ in shown])
        train_rows, held_rows = rows[:count], rows[count:]
        ucd = [r["ucd"] for r in train_rows if r["ucd"] is not None]
        for split, part in (("training", train_rows), ("held-out", held_rows)):
            empty = [r["name"] for r in part if r["ucd"] is None]
            if empty:  # an empty mesh has no UCD: the means below are over the others, and would flatter the run
                log.warning("%d of %d %s shapes meshed empty (%s): ucd and boundary_error are over the other %d; "
                            "metrics.json counts them in empty_meshes%s.", len(empty), len(part), split,
                            ", ".join(empty[:5]) + (", ..." if len(empty) > 5 else ""), len(part) - len(empty),
                            "" if split == "training" else "_held_out")
        be = [r["boundary_error"] for r in train_rows if r["boundary_error"] is not None]
        metrics: dict[str, Any] = {
            # the last training step's loss; null when this process trained no step (a resumed run at its budget)
            "loss": float(self.trainer.callback_metrics["train/loss"])
            if self._trainer is not None and "train/loss" in self.trainer.callback_metrics else None,
            "ucd": float(np.mean(ucd)) if ucd else None,
            "ucd_worst": float(np.max(ucd)) if ucd else None,
            "ucd_worst_index": int(train_rows[int(np.argmax([r["ucd"] if r["ucd"] is not None else -1
                                                             for r in train_rows]))]["index"]) if ucd else None,
            "ucd_reverse": float(np.mean([r["ucd_reverse"] for r in train_rows if r["ucd_reverse"] is not None]))
            if ucd else None,
            "boundary_error": float(np.mean(be)) if be else None,
            "boundary_error_worst": float(np.max(be)) if be else None,
            "empty_meshes": sum(r["ucd"] is None for r in train_rows),
            "shapes_evaluated": count,
            "num_shapes": self.num_shapes,
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
                "latent_fit_seconds": fit_seconds,
            })
        metrics.update(self.run_metrics())
        return self.write_metrics(out_dir, metrics)
