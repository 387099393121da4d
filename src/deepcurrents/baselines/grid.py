"""The grid baseline of paper Fig. 4 (Wang & Chern 2021) as a LightningModule: φ on N³ voxels, one ADMM
iteration per training step (numerics in ``deepcurrents.baselines.grid_solver``), stopped on its
residuals. It goes through the same ``train.py``, logging, checkpoints and meshing as the network.
"""

from __future__ import annotations

import logging
import math
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from deepcurrents.baselines.grid_current import ADMM, DTYPES, GridCurrent
from deepcurrents.baselines.grid_solver import (
    ADMMReport,
    GridProblem,
    cap_singularity,
    grid_spacing,
    grid_vertices,
)
from deepcurrents.errors import ConfigError
from deepcurrents.eval.device import require_memory
from deepcurrents.eval.meshing import extract_surface, mesh_method, mesh_region
from deepcurrents.eval.metrics import mass_estimate, mass_to_area
from deepcurrents.geometry import biot_savart
from deepcurrents.models.base import DeepCurrentsModule, network_kwargs
from deepcurrents.models.current_module import input_frame, input_mesh, metrics_in_input_units
from deepcurrents.nn import neural_current

log = logging.getLogger(__name__)

def matched_resolution(net: dict[str, Any], rff: dict[str, Any] | None, loops: list[torch.Tensor]) -> tuple[int, int]:
    """The grid size N with N³ closest to the parameter count of the network ``net`` and ``rff`` describe
    (trainable weights + frozen Fourier frequencies, as the paper counts 725,249 → 90³). → (N, count)."""
    network = neural_current(dim=3, loops=loops, **network_kwargs(net, rff))
    count = sum(p.numel() for p in network.parameters()) + network.encoding.frequencies.numel()
    return max(4, round(count ** (1.0 / 3.0))), count


# Bytes a grid corner takes while training (α at the corners, φ, ADMM's split variable, its multiplier and the
# iteration's temporaries, then the final evaluation's field): the peak RSS of `minimal_grid` runs at N = 60 and
# 120 in float64 grew by 340 bytes a corner; a little less here, so that only grids that cannot fit are refused.
GRID_CORNER_BYTES = 300


def check_grid_memory(resolution: int, dtype: torch.dtype) -> None:
    """One sentence if an N³ grid's arrays cannot fit in the memory available here (N = 5000 asked for 1 TB in
    one allocation, a raw RuntimeError from torch's allocator)."""
    require_memory(f"model.grid.resolution={resolution}",
                   GRID_CORNER_BYTES * (resolution + 1) ** 3 * torch.finfo(dtype).bits // 64)


class GridModule(DeepCurrentsModule):
    """Minimal currents on a voxel grid (Wang & Chern 2021; paper Fig. 4), solved by ADMM.

    Args:
        boundary: ``boundary_spec`` of Γ ({"loops": [...]}); 3D only.
        grid: {"resolution": N or null, "dtype": "float64"|"float32"}. N³ cells over [-1, 1]³; null sizes
            the grid like the network in ``net`` (the paper's matched parameter count: 90³).
        admm: {"rho", "relaxation", "balance", "tol", "min_iterations"}: initial penalty ρ = rho·h/alpha_scale
            (the shrink threshold 1/ρ then sits at the same place relative to |ω| at every N), over-relaxation,
            residual balancing (0: off), stop when both relative residuals are below tol.
        net, rff: the network this grid is compared with (model/current.yaml's blocks): ``alpha_scale`` is
            the shared normalisation of ω; their sizes give the matched resolution.
        optim: the network's optimiser settings, unused (ADMM has no learning rate); accepted so that
            presets that size the network (preset=cpu) compose with this model.
        evaluation: {"mass_samples", "seed", "mesh": {...extract_surface kwargs}}.
    """

    def __init__(self, boundary: dict, grid: dict, admm: dict, net: dict, optim: dict | None = None,
                 rff: dict | None = None, evaluation: dict | None = None, grid_encoding: dict | None = None):
        # ADMM has no learning rate and no network: `optim` and `grid_encoding` are accepted, unused
        super().__init__(optim=None)
        self.save_hyperparameters()
        self.automatic_optimization = False
        self.evaluation = dict(evaluation or {})
        if "loops" not in boundary:
            raise ConfigError("model=grid needs a 3D boundary (closed loops); 2D point boundaries are not supported.")
        # the settings of model.grid, model.admm and model.net are checked before anything is built
        # (experiments.schema); the grid's size against the memory here, once it is known
        loops = [torch.tensor(lp, dtype=torch.float64) for lp in boundary["loops"]]
        alpha_scale = float(net.get("alpha_scale", 1e-3))
        dtype = str(grid.get("dtype", "float64"))
        resolution = grid.get("resolution")
        self.matched_parameters = None
        if resolution is None:
            resolution, self.matched_parameters = matched_resolution(net, rff, loops)
        check_grid_memory(resolution, DTYPES[dtype])
        self.admm_settings = {"rho": float(admm.get("rho", 0.5)), "relaxation": float(admm.get("relaxation", 1.6)),
                              "balance": float(admm.get("balance", 10.0)), "tol": float(admm.get("tol", 1e-3)),
                              "min_iterations": int(admm.get("min_iterations", 10))}
        self.current = GridCurrent(resolution, loops, alpha_scale, DTYPES[dtype])
        self._problem: GridProblem | None = None
        self.setup_seconds = 0.0
        self.converged = False

    @property
    def dim(self) -> int:
        return 3

    @property
    def resolution(self) -> int:
        return self.current.resolution

    def problem(self) -> GridProblem:
        """α_Γ at the corners (scaled, |α| capped next to Γ) on φ's device, computed once."""
        phi = self.current.phi
        if self._problem is None or self._problem.alpha.device != phi.device:
            start = time.perf_counter()
            n, h = self.resolution, grid_spacing(self.resolution)
            corners = grid_vertices(n, phi.device, phi.dtype).reshape(-1, 3)
            alpha = biot_savart(corners, [lp.to(phi) for lp in self.current.loops])
            alpha = alpha.T.reshape(3, n + 1, n + 1, n + 1)
            self.current.set_corner_alpha(self.current.alpha_scale * cap_singularity(alpha, h))
            self._problem = GridProblem.from_alpha(self.current.corner_alpha)
            self.setup_seconds = time.perf_counter() - start
        return self._problem

    def on_load_checkpoint(self, checkpoint: dict) -> None:
        super().on_load_checkpoint(checkpoint)
        self.problem()  # α at the corners, which ω needs: a checkpoint opened by an app has not trained

    def configure_optimizers(self):
        h = grid_spacing(self.resolution)
        s = self.admm_settings
        return ADMM(self.current.phi, self.problem, rho=s["rho"] * h / self.current.alpha_scale,
                    relaxation=s["relaxation"], balance=s["balance"])

    def training_step(self, batch: Any, batch_idx: int) -> None:
        opt = self.optimizers()
        opt.step()
        report: ADMMReport = opt.optimizer.last
        self.check_finite(report.mass, hint="try a smaller model.admm.rho")
        s = self.admm_settings
        if self.global_step >= s["min_iterations"] and max(report.primal, report.dual) < s["tol"]:
            self.converged = True
            self.trainer.should_stop = True
        # only on the steps the loggers write: each self.log costs more than a small ADMM iteration
        if self.global_step % max(1, self.trainer.log_every_n_steps) == 0 or self.converged:
            area = report.mass / (4.0 * math.pi * self.current.alpha_scale)
            self.log_dict({"train/loss": report.mass / 8.0, "train/mass_area": area,
                           "train/primal_residual": report.primal, "train/dual_residual": report.dual,
                           "train/rho": report.rho}, prog_bar=True)

    def on_train_start(self) -> None:
        self.problem()  # α before the clock starts: its time is reported as setup_seconds
        super().on_train_start()

    def final_mesh_regions(self) -> list[np.ndarray]:
        """The region the final mesh covers (``meshing.mesh_region`` of the evaluation's mesh settings)."""
        loops = [lp.detach().cpu().double().numpy() for lp in self.current.loops]
        return [mesh_region(loops, dict(self.evaluation.get("mesh", {})))]

    @torch.no_grad()
    def final_evaluation(self, out_dir: str | Path) -> dict[str, Any]:
        """metrics.json, mesh.ply, mesh.png and field.npz (φ and |ω| on the grid) in ``out_dir``. → metrics."""
        out_dir = Path(out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        problem = self.problem()
        phi = self.current.phi.detach()
        omega = problem.current(phi)
        scale = 1.0 / (4.0 * math.pi * self.current.alpha_scale)  # mass → area (the jump of Ω is 4π)
        mass = problem.mass(omega)
        # the multiplier Λ = ρu certifies how far the iteration stopped from the discrete optimum
        opt_state = self._optimizer_state()
        dual = problem.dual_bound(opt_state["rho"] * opt_state["u"]) if opt_state else None
        samples = int(self.evaluation.get("mass_samples", 1 << 20))
        mc, mc_err = mass_estimate(self.current, samples, seed=int(self.evaluation.get("seed", 12345)))
        metrics: dict[str, Any] = {
            "loss": mass / 8.0,
            "mass_area": mass * scale,
            "mass_area_lower": dual * scale if dual is not None else None,
            "mass_area_mc": mass_to_area(mc, 3, self.current.alpha_scale),
            "mass_area_mc_stderr": mass_to_area(mc_err, 3, self.current.alpha_scale),
            "resolution": self.resolution,
            "parameters": int(phi.numel()),
            "iterations": int(opt_state["iteration"]) if opt_state else 0,
            **self.run_metrics(),  # train_seconds: the ADMM iterations
            "converged": bool(self.converged),
            "setup_seconds": round(self.setup_seconds, 3),  # sampling α at the corners
            "seconds": round(self.train_seconds + self.setup_seconds, 3),
        }
        if self.matched_parameters is not None:
            metrics["matched_network_parameters"] = int(self.matched_parameters)
        last = self.trainer.optimizers[0].last if opt_state else None
        if last is not None:
            metrics["primal_residual"], metrics["dual_residual"] = last.primal, last.dual
        result = extract_surface(self.current, **mesh_method(self.evaluation.get("mesh", {}), self.mesh_method),
                                 resolution_key=self.MESH_RESOLUTION_KEY)
        loops = [lp.cpu().double().numpy() for lp in self.current.loops]
        name = self.hparams.boundary.get("name", "")
        frame = input_frame(self.hparams.boundary)  # a normalised curve: outputs in the input's units
        metrics.update(self.write_mesh(out_dir, result, loops,
                                       f"{name} grid {self.resolution}³: area {result.mesh.area:.4f}",
                                       export=input_mesh(result.mesh, frame) if frame is not None else None))
        if frame is not None:
            metrics = metrics_in_input_units(metrics, *frame)
        np.savez(out_dir / "field.npz", phi=phi.cpu().numpy(), omega_norm=omega.norm(dim=0).float().cpu().numpy(),
                 resolution=self.resolution, alpha_scale=self.current.alpha_scale,
                 cell_centers_axis=(-1.0 + grid_spacing(self.resolution) * (np.arange(self.resolution) + 0.5)))
        return self.write_metrics(out_dir, metrics)

    def _optimizer_state(self) -> dict | None:
        if self._trainer is None or not self.trainer.optimizers:
            return None
        state = self.trainer.optimizers[0].state.get(self.current.phi)
        return state or None
