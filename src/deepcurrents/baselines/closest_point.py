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
from deepcurrents.models.base import DeepCurrentsModule, network_kwargs
from deepcurrents.models.reconstruction import TargetGeometry
from deepcurrents.nn import FieldMLP, FourierFeatures

log = logging.getLogger(__name__)


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

    Batches: ``ReconstructionDataModule(batch_kind="closest_point")`` → {"x", "closest"}.
    Stops when the training time reaches ``time_budget_s`` (or the ``train_seconds`` read from
    ``wall_time_from`` when training starts) or at ``trainer.max_steps``, whichever comes first: the
    recon_baseline experiment caps steps at 1e6 under every preset, so that its budget is the stop.
    """

    def __init__(self, net: dict, optim: dict, rff: dict | None = None, evaluation: dict | None = None,
                 target: dict | None = None, boundary: dict | None = None, near_fraction: float = 0.5,
                 near_sigma: float = 0.05,
                 time_budget_s: float | None = None, wall_time_from: str | None = None):
        super().__init__(optim)
        self.save_hyperparameters(ignore=["target"])
        if time_budget_s is not None and not float(time_budget_s) > 0:
            raise ConfigError(f"model.time_budget_s={time_budget_s} must be positive.")
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

    def on_train_start(self) -> None:
        if self.wall_time_from is not None and self.time_budget_s is None:
            self.time_budget_s = read_wall_time(self.wall_time_from)
            log.info("closest-point baseline: training for %.1f s (the wall time of %s)", self.time_budget_s,
                     self.wall_time_from)
        super().on_train_start()

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
        ``ucd_reverse`` = mean distance to the target of predicted points g(x) for x near the target;
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
        near = y + rng.normal(scale=float(self.hparams.near_sigma), size=y.shape)
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
        trimesh.PointCloud(TargetGeometry.to_input(self, pred)).export(out_dir / "points.ply")
        return self.write_metrics(out_dir, metrics)
