"""The LightningModule for one current ω = ∇f_θ + α_Γ: minimal surfaces in 3D and 2D (B = I)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch

from deepcurrents.eval.meshing import extract_curve_2d, extract_surface, mesh_method
from deepcurrents.eval.metrics import curve_length, mass_estimate, mass_to_area
from deepcurrents.eval.plots import plot_current_2d
from deepcurrents.losses import current_loss
from deepcurrents.models.base import DeepCurrentsModule, network_kwargs
from deepcurrents.nn import NeuralCurrent


def boundary_spec(boundary) -> dict[str, Any]:
    """A plain-data description of a Boundary/PointBoundary (stored in hyperparameters and checkpoints)."""
    if hasattr(boundary, "loops"):
        return {"loops": [np.asarray(lp).tolist() for lp in boundary.loops], "name": boundary.name}
    return {"poles": np.asarray(boundary.points).tolist(), "signs": np.asarray(boundary.signs).tolist(),
            "name": boundary.name}


class CurrentModule(DeepCurrentsModule):
    """Minimal surfaces (paper §5.1) and 2D curves (Fig. 3b): minimise E|ω| over uniform samples of U.

    Args:
        boundary: ``boundary_spec`` of Γ: {"loops": [...]} in 3D or {"poles", "signs"} in 2D.
        net: the MLP and ω's normalisation (width, depth, activation, alpha_scale, zero_init_output).
        rff: the random Fourier features (num_frequencies, sigma, enabled, seed).
        optim: {"lr", "step_size", "gamma"} — Adam with lr × gamma every step_size steps.
        evaluation: {"mass_samples", "mesh": {...extract_surface kwargs}, "curve": {...}}.
    """

    def __init__(self, boundary: dict, net: dict, optim: dict, rff: dict | None = None,
                 evaluation: dict | None = None):
        super().__init__(optim)
        self.save_hyperparameters()
        self.evaluation = dict(evaluation or {})
        net = network_kwargs(net, rff)
        if "loops" in boundary:
            self.current = NeuralCurrent(dim=3, loops=[torch.tensor(lp) for lp in boundary["loops"]], **net)
        else:
            self.current = NeuralCurrent(dim=2, poles=torch.tensor(boundary["poles"]),
                                         signs=torch.tensor(boundary["signs"]), **net)

    @property
    def dim(self) -> int:
        return self.current.dim

    def training_step(self, batch: dict[str, torch.Tensor], batch_idx: int) -> torch.Tensor:
        _, omega = self.current(batch["x"], create_graph=True, alpha=batch.get("alpha"))
        loss = current_loss(omega, batch.get("metric"), batch.get("weight"))
        self.check_finite(loss)
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
        samples = int(self.evaluation.get("mass_samples", 1 << 20))
        rel = self.evaluation.get("mass_rel_stderr")  # stop early once the estimate is this precise
        used: dict[str, int] = {}
        mass, stderr = mass_estimate(self.current, samples, seed=int(self.evaluation.get("seed", 12345)),
                                     rel_stderr=float(rel) if rel else None, info=used)
        scale = mass_to_area(1.0, self.dim, self.current.alpha_scale)
        metrics: dict[str, Any] = {"loss": mass, **self.run_metrics(), "mass_samples": used["samples"]}
        name = "area" if self.dim == 3 else "length"
        metrics[f"mass_{name}"] = mass * scale
        metrics[f"mass_{name}_stderr"] = stderr * scale
        if self.dim == 3:
            result = extract_surface(self.current, **self.mesh_options())
            self.meshing = result  # subclasses evaluate the same mesh further
            loops = [lp.cpu().double().numpy() for lp in self.current.loops]
            title = f"{self.hparams.boundary.get('name', '')}: area {result.mesh.area:.4f}"
            metrics.update(self.write_mesh(out_dir, result, loops, title))
        else:
            curves = extract_curve_2d(self.current, **self.evaluation.get("curve", {}))
            metrics["curve_length"] = curve_length(curves)
            poles = self.current.poles.cpu().numpy()
            ends = np.concatenate([c[[0, -1]] for c in curves]) if curves else np.zeros((0, 2))
            metrics["boundary_error"] = (
                float(np.linalg.norm(poles[:, None] - ends[None], axis=-1).min(1).max()) if len(ends) else None
            )
            np.savez(out_dir / "curve.npz", *curves)
            self._plot_2d(curves, out_dir / "current.png")
        return self.write_metrics(out_dir, metrics)

    def mesh_options(self) -> dict[str, Any]:
        """Keyword arguments of ``extract_surface`` for the final mesh (reconstruction adds ``bounds``)."""
        return mesh_method(self.evaluation.get("mesh", {}), self.mesh_method)

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
