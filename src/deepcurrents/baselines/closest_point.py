"""The baseline of the paper's Table 1: a closest-surface-point network in the manner of Venkatesh et al.
(ICCV 2021, "Deep Implicit Surface Point Prediction Networks"): g_θ(x) = x + h_θ(x) predicts the closest
point of the target to any x, trained by regression on exact closest points, for the same wall-clock time
as a DeepCurrents run. As in the paper, its UCD is E_{y ~ U(Σ)} |y − g_θ(y)|: the distance from a target
point to the learned surface is the distance to the point the network says is closest.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

import numpy as np
import torch

from deepcurrents.errors import ConfigError
from deepcurrents.eval.metrics import sample_surface
from deepcurrents.geometry.meshes import write_mesh
from deepcurrents.models.base import DeepCurrentsModule, network_kwargs
from deepcurrents.models.reconstruction import TargetGeometry
from deepcurrents.nn import FieldMLP, FourierFeatures

log = logging.getLogger(__name__)

# σ of the Gaussian noise around target samples whose images g(x) ``ucd_reverse`` measures. A fixed part of the
# evaluation, so that runs compare whatever they trained with; 0.05 is the value every earlier run's
# model.near_sigma had (it was read here and nowhere else), so their ucd_reverse is unchanged.
REVERSE_NEAR_SIGMA = 0.05

# Settings of earlier versions that no training read (the near/uniform split is data.num_samples /
# data.num_surface_samples, the noise data.near_sigma); their checkpoints still carry them as hyperparameters.
RETIRED = {"near_fraction": "data.num_surface_samples (points near the target) beside data.num_samples (uniform)",
           "near_sigma": "data.near_sigma (the noise of the points near the target)"}


def read_wall_time(path: str | Path) -> float:
    """``train_seconds`` of a finished run (its metrics.json); ConfigError when it is not there."""
    path = Path(path)
    try:
        return float(json.loads(path.read_text())["train_seconds"])
    except (OSError, KeyError, ValueError, TypeError) as err:
        raise ConfigError(f"model.wall_time_from='{path}' is not a run's metrics.json with train_seconds "
                          f"({err}).") from err


class ClosestPointModule(DeepCurrentsModule):
    """x ↦ g(x) = x + h(x), h the Fourier-feature MLP with 3 outputs; loss E|g(x) − proj_Σ(x)|².

    Batches: ``ReconstructionDataModule(batch_kind="closest_point")`` → {"x", "closest"}: ``data.num_samples``
    uniform points and ``data.num_surface_samples`` near Σ (noise σ = ``data.near_sigma``); the data owns them.
    Stops when the training time reaches ``time_budget_s`` (or the ``train_seconds`` read from
    ``wall_time_from`` when training starts) or at ``trainer.max_steps``, whichever comes first: the
    recon_baseline experiment caps steps at 1e6 under every preset, so that its budget is the stop. A run
    resumed with its budget used trains no step; one without a budget says so (a warning) when it starts.
    """

    def __init__(self, net: dict, optim: dict, rff: dict | None = None, evaluation: dict | None = None,
                 target: dict | None = None, boundary: dict | None = None,
                 time_budget_s: float | None = None, wall_time_from: str | None = None,
                 near_fraction: float | None = None, near_sigma: float | None = None):
        super().__init__(optim)
        # near_fraction, near_sigma: RETIRED, accepted so that earlier checkpoints (whose hyperparameters are
        # passed back here) still load; not saved, and refused in training (setup)
        self.save_hyperparameters(ignore=["target", "near_fraction", "near_sigma"])
        self._retired = {k: v for k, v in (("near_fraction", near_fraction), ("near_sigma", near_sigma))
                         if v is not None}
        net = network_kwargs(net, rff)
        self.encoding = FourierFeatures(3, net["num_frequencies"], float(net["sigma"]), enabled=net["rff"],
                                        seed=net["rff_seed"])
        self.mlp = FieldMLP(self.encoding.out_dim, net["width"], net["depth"], net.get("activation", "softplus"),
                            out_dim=3)
        self.evaluation = dict(evaluation or {})
        self.time_budget_s = float(time_budget_s) if time_budget_s is not None else None
        self.wall_time_from = wall_time_from
        TargetGeometry.register(self, target)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Predicted closest points. (N, 3) → (N, 3)."""
        return x + self.mlp(self.encoding(x))

    def setup(self, stage: str) -> None:
        # a fit builds the module from the run's config (a resume too), never from a checkpoint's hyperparameters:
        # a retired setting here was given on the command line (+model.near_fraction=...) and would do nothing
        if stage == "fit" and self._retired:
            key = next(iter(self._retired))
            raise ConfigError(f"model.{key} is not a setting of the closest-point baseline any more (it was never "
                              f"read); set {RETIRED[key]} instead.")

    def on_train_start(self) -> None:
        if self.wall_time_from is not None and self.time_budget_s is None:
            self.time_budget_s = read_wall_time(self.wall_time_from)
            log.info("closest-point baseline: training for %.1f s (the wall time of %s)", self.time_budget_s,
                     self.wall_time_from)
        super().on_train_start()
        if self.time_budget_s is None:
            steps = self.trainer.max_steps
            limit = f"trainer.max_steps={steps} steps" if steps is not None and steps >= 0 else "trainer.max_time"
            if self.trainer.is_global_zero:  # (the other ranks: no budget to compare with below either)
                    log.warning("The closest-point baseline has no wall-time budget (neither model.wall_time_from nor "
                            "model.time_budget_s is set), so it trains until %s (Table 1 gives it a DeepCurrents "
                            "run's time: model.wall_time_from=RUN/metrics.json).", limit)
        elif self.train_seconds >= self.time_budget_s:
            # a resumed run whose budget is used (a finished table1 resumed with ckpt_path=auto): train nothing, as
            # a run resumed at its max_steps, and stop the clock so that train_seconds stays the checkpoint's.
            # should_stop before the loop's first check: no batch is drawn and the lr schedule does not move.
            log.info("closest-point baseline: its wall-time budget (%.1f s) is used (%.1f s trained); no step "
                     "will be trained.", self.time_budget_s, self.train_seconds)
            self._train_start = None
            self.trainer.should_stop = True

    def training_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> torch.Tensor:
        loss = ((self(batch["x"]) - batch["closest"]) ** 2).sum(-1).mean()
        self.check_finite(loss)
        if self.logs_this_step():
            self.log("train/loss", loss, prog_bar=True)
        return loss

    def on_train_batch_end(self, outputs, batch, batch_idx: int) -> None:
        if self.time_budget_s is not None and self.elapsed_train_seconds() >= self.time_budget_s:
            self.trainer.should_stop = True

    @torch.no_grad()
    def predict_points(self, x: np.ndarray, chunk: int = 1 << 15) -> np.ndarray:
        dev = next(self.parameters()).device
        out = [self(torch.as_tensor(c, dtype=torch.float32, device=dev)).double().cpu().numpy()
               for c in np.array_split(x, max(1, len(x) // chunk))]
        return np.concatenate(out)

    @torch.no_grad()
    def final_evaluation(self, out_dir: str | Path) -> dict[str, Any]:
        """``ucd`` = mean |y − g(y)| over uniform target samples (the paper's evaluation of this baseline);
        ``ucd_reverse`` = mean distance to the target of predicted points g(x) for x = y + N(0, σ²), σ =
        ``REVERSE_NEAR_SIGMA`` (fixed: not a training setting);
        ``points.ply`` holds those predicted points."""
        import trimesh

        from deepcurrents.eval.metrics import point_mesh_distance

        out_dir = Path(out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        self.eval()
        n = int(self.evaluation.get("ucd_samples", 100_000))
        seed = int(self.evaluation.get("seed", 12345))
        target = TargetGeometry.mesh(self)
        if target is not None:
            y = sample_surface(target, n, seed)
        else:
            y = TargetGeometry.points(self)
        pred_y = self.predict_points(y)
        rng = np.random.default_rng(seed + 1)
        near = y + rng.normal(scale=REVERSE_NEAR_SIGMA, size=y.shape)
        pred = self.predict_points(near)
        if target is not None:
            reverse = float(point_mesh_distance(pred, target).mean())
        else:
            from scipy.spatial import cKDTree

            reverse = float(cKDTree(y).query(pred)[0].mean())
        ucd = float(np.linalg.norm(pred_y - y, axis=1).mean())
        metrics = {"ucd": ucd, "ucd_reverse": reverse, "chamfer": 0.5 * (ucd + reverse),
                   "loss": float(((pred_y - y) ** 2).sum(1).mean()), **self.run_metrics(),
                   "target": self.target_source}
        frame = TargetGeometry.frame(self)
        if frame is not None:  # a normalised target: the UCD in the file's units as well, as ReconstructionModule
            metrics["ucd_input_units"] = ucd * frame[0]
            metrics["ucd_reverse_input_units"] = reverse * frame[0]
        write_mesh(trimesh.PointCloud(TargetGeometry.to_input(self, pred)), out_dir / "points.ply")
        return self.write_metrics(out_dir, metrics)
