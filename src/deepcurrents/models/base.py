"""What every DeepCurrents LightningModule shares: Adam with the paper's step decay, the NaN guard, the
training clock, the run's configuration stored in each checkpoint (so apps can rebuild any model kind from a
checkpoint), and the files of a final evaluation (metrics.json, the mesh and its picture)."""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any

import lightning as L
import numpy as np
import torch
import trimesh

from deepcurrents.errors import NonFiniteLossError
from deepcurrents.eval.meshing import grid_shape
from deepcurrents.eval.metrics import mesh_summary, metrics_json
from deepcurrents.eval.plots import MeshView, plot_mesh
from deepcurrents.geometry.meshes import write_mesh
from deepcurrents.models.checkpointing import kept_checkpoint
from deepcurrents.models.schedules import BudgetCosine, trainer_progress

CHECKPOINT_KEY = "deepcurrents"


RFF_KEYS = {"num_frequencies", "sigma", "enabled", "seed", "coarse_to_fine", "coarse_start"}
GRID_ENCODING_KEYS = {"levels", "base_resolution", "finest_resolution", "features", "table_size", "init_scale",
                      "lr_factor"}


def network_kwargs(net: dict[str, Any], rff: dict[str, Any] | None = None,
                   grid_encoding: dict[str, Any] | None = None) -> dict[str, Any]:
    """``model.net`` (the MLP: width, depth, activation, alpha_scale, ...), ``model.rff`` (the random Fourier
    features: num_frequencies, sigma, enabled, seed, coarse_to_fine, coarse_start; ``nn.FourierFeatures``) and
    ``model.grid_encoding`` (learned multiresolution grid features, ``nn.MultiresGrid``; levels 0 = off) as the
    keyword arguments of ``nn.neural_current`` and ``FamilyCurrent`` (the values are checked before anything is
    built, ``experiments.schema``)."""
    rff = dict(rff or {})
    kwargs = dict(net)
    kwargs.update(num_frequencies=rff.get("num_frequencies", 1024), sigma=rff.get("sigma", 2.0),
                  rff=bool(rff.get("enabled", True)), rff_seed=rff.get("seed"))
    coarse_to_fine = float(rff.get("coarse_to_fine", 0.0))
    if coarse_to_fine > 0:
        kwargs.update(coarse_to_fine=coarse_to_fine, coarse_start=float(rff.get("coarse_start", 0.25)))
    grid = dict(grid_encoding or {})
    grid.pop("lr_factor", None)  # an optimiser setting (CurrentModule.parameter_groups), not the network's
    levels = grid.pop("levels", 0) or 0
    if levels > 0:
        kwargs["grid"] = {"levels": int(levels), **grid}
    return kwargs


# the settings of model.optim that configure_optimizers and the schedules read
OPTIM_KEYS = ("lr", "step_size", "gamma", "schedule", "warmup", "min_factor", "fused", "betas")


class DeepCurrentsModule(L.LightningModule):
    """Base class of every model kind. Subclasses define ``training_step`` and ``final_evaluation``.

    ``optim`` ({"lr", "step_size", "gamma"}: Adam with lr × gamma every step_size steps; optional
    "schedule": "cosine" with "warmup" and "min_factor" follows the run's budget instead, models.schedules;
    optional "betas": Adam's; optional "fused": PyTorch's fused Adam kernel) may be None for
    models that bring their own optimiser (the grid baseline's ADMM overrides ``configure_optimizers``).
    Training time (``train_seconds``) counts only the fit loop, across resumes: it is carried by every
    checkpoint and restored from it.
    """

    mesh_method = "phase"  # what evaluation.mesh.method=auto means for this model kind (eval.meshing.mesh_method)

    def __init__(self, optim: dict[str, Any] | None):
        super().__init__()  # ``optim``'s settings are checked before anything is built (experiments.schema)
        self.run_config: dict | None = None  # set by the entry point; saved in checkpoints
        self.train_seconds = 0.0  # training time of the fit loops that ended (this run and those it resumed)
        self._train_start: float | None = None
        # the deferred finiteness check (check_finite): first bad step (−1: none) and its loss, on the device
        self._first_bad: torch.Tensor | None = None
        self._bad_value: torch.Tensor | None = None
        self._bad_hint = "try a lower model.optim.lr"

    def configure_optimizers(self):
        optim = self.hparams.optim
        betas = tuple(float(b) for b in optim.get("betas") or (0.9, 0.999))
        # fused: one kernel per step instead of a dozen passes (much faster over a grid encoding's table); off by
        # default, since it rounds differently from the loop the authors' recipe ran
        opt = torch.optim.Adam(self.parameter_groups(float(optim["lr"])), lr=float(optim["lr"]), betas=betas,
                               fused=bool(optim.get("fused", False)) or None)
        if optim.get("schedule", "step") == "cosine":  # the horizon is the budget (models.schedules)
            sched = BudgetCosine(opt, lambda: trainer_progress(self.trainer, self.global_step),
                                 float(optim.get("warmup", 0.0)), float(optim.get("min_factor", 0.0)))
        else:  # the authors' step decay
            sched = torch.optim.lr_scheduler.StepLR(opt, step_size=int(optim["step_size"]),
                                                    gamma=float(optim["gamma"]))
        return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "step"}}

    def parameter_groups(self, lr: float) -> list[dict]:
        """Adam's parameter groups; one at ``lr`` unless a model kind trains some parameters at another rate."""
        return [{"params": list(self.parameters())}]

    # the setting that sizes the final mesh's grid, named when that grid cannot fit in memory
    MESH_RESOLUTION_KEY = "evaluation.mesh.resolution"

    def final_mesh_regions(self) -> list[np.ndarray]:
        """The regions (2, 3) the final evaluation will mesh at ``evaluation.mesh.resolution`` (none by default;
        model kinds that mesh say which)."""
        return []

    def check_final_mesh(self) -> None:
        """Before training: one sentence if a grid of the final mesh cannot fit in this machine's memory
        (``meshing.grid_shape``), instead of a failure after the training it follows."""
        resolution = dict(dict(getattr(self, "evaluation", None) or {}).get("mesh") or {}).get("resolution")
        if resolution is None:
            return
        for bounds in self.final_mesh_regions():
            grid_shape(np.asarray(bounds, dtype=np.float64), int(resolution), self.MESH_RESOLUTION_KEY)

    def check_finite(self, loss: torch.Tensor | float, hint: str = "try a lower model.optim.lr") -> None:
        """Stops training with one sentence when the loss is NaN or infinite. Every ``model.optim.check_every``
        steps (null: 1 on a CPU; 32 on a GPU, where reading a value on the host each step stalls the device) the
        loss is read; between reads the first bad step and its value are kept on the device, and are read before
        any checkpoint is written (``on_save_checkpoint``) and when training ends, so no checkpoint holds the
        weights of a step after a bad loss."""
        if not isinstance(loss, torch.Tensor) or self.check_every(loss.device) <= 1:
            self._raise_if_bad(float(loss.detach()) if isinstance(loss, torch.Tensor) else float(loss),
                               self.global_step, hint)
            return
        loss = loss.detach()
        if self._first_bad is None:
            self._first_bad = torch.full((), -1, dtype=torch.long, device=loss.device)
            self._bad_value = torch.zeros((), dtype=loss.dtype, device=loss.device)
        new = (~torch.isfinite(loss)) & (self._first_bad < 0)
        self._first_bad = torch.where(new, torch.full_like(self._first_bad, self.global_step), self._first_bad)
        self._bad_value = torch.where(new, loss, self._bad_value)
        self._bad_hint = hint
        if (self.global_step + 1) % self.check_every(loss.device) == 0:
            self.read_finite_check()

    def check_every(self, device: torch.device) -> int:
        """``model.optim.check_every``, or its default for ``device``: 1 on a CPU, 32 on an accelerator."""
        every = ((getattr(self, "hparams", None) or {}).get("optim") or {}).get("check_every")
        return int(every) if every is not None else (1 if device.type == "cpu" else 32)

    def read_finite_check(self) -> None:
        """Raises the deferred check's sentence if some step since the start had a bad loss (one host read)."""
        if self._first_bad is not None and (step := int(self._first_bad)) >= 0:
            self._raise_if_bad(float(self._bad_value), step, self._bad_hint)

    def _raise_if_bad(self, value: float, step: int, hint: str) -> None:
        if not math.isfinite(value):
            # self._trainer: None outside a fit (the property would raise then)
            raise NonFiniteLossError(f"The loss became {value} at step {step}; training stopped, and "
                                     f"{kept_checkpoint(self._trainer)} ({hint}).")

    # ------------------------------------------------------------------------------- training clock
    def elapsed_train_seconds(self) -> float:
        """Training seconds so far, including the running fit loop."""
        running = time.perf_counter() - self._train_start if self._train_start is not None else 0.0
        return self.train_seconds + running

    def on_train_start(self) -> None:
        self._train_start = time.perf_counter()
        # modules that change with the budget used: coarse-to-fine Fourier features, delayed phase harmonics
        self._follow_progress = [m for m in self.modules() if getattr(m, "follows_progress", False)]

    def on_train_batch_start(self, batch: Any, batch_idx: int) -> None:
        # they follow the budget used (steps or seconds), as the cosine lr does (recomputed from the restored
        # step and clock, so a resumed run sets the values the uninterrupted one had)
        for module in getattr(self, "_follow_progress", ()):
            module.set_progress(trainer_progress(self.trainer, self.global_step))

    def on_train_end(self) -> None:
        self.read_finite_check()  # a bad loss in the last steps since the last read
        self.train_seconds = self.elapsed_train_seconds()
        self._train_start = None  # a checkpoint written after training must not count the time since

    def logs_this_step(self) -> bool:
        """Whether Lightning writes this training step's logged values to the loggers: every
        ``trainer.log_every_n_steps`` steps (counted as Lightning does, step + 1), when the trainer stops, and on the
        last step of a step budget (whose values the final metrics read from ``trainer.callback_metrics``).
        ``self.log`` on the other steps only refreshes the progress bar at a measurable share of a small step
        (docs/notes/speed.md), so the model kinds log only on these steps; the loggers receive the same values."""
        trainer = self._trainer
        if trainer is None:  # called outside a fit (a test): log as Lightning would decide
            return True
        every, step = int(trainer.log_every_n_steps or 0), self.global_step + 1
        last = trainer.max_steps is not None and 0 < trainer.max_steps <= step  # its values end in callback_metrics
        return every > 0 and (step % every == 0 or trainer.should_stop or last)

    # ----------------------------------------------------------------------------------- checkpoints
    def on_save_checkpoint(self, checkpoint: dict) -> None:
        self.read_finite_check()  # before the file is written: a checkpoint never holds weights after a bad step
        checkpoint[CHECKPOINT_KEY] = {
            "module": f"{type(self).__module__}.{type(self).__qualname__}",
            "config": self.run_config,
        }
        checkpoint["train_seconds"] = self.elapsed_train_seconds()

    def on_load_checkpoint(self, checkpoint: dict) -> None:
        self.train_seconds = float(checkpoint.get("train_seconds", 0.0))

    # ------------------------------------------------------------------------------ final evaluation
    def run_metrics(self) -> dict[str, Any]:
        """The bookkeeping every metrics.json starts with: steps and training seconds."""
        return {"steps": int(self.global_step), "train_seconds": round(self.train_seconds, 3)}

    @staticmethod
    def write_metrics(out_dir: str | Path, metrics: dict[str, Any]) -> dict[str, Any]:
        """``out_dir/metrics.json`` (flat, strict JSON: a NaN is written as null). → metrics."""
        out_dir = Path(out_dir)
        out_dir.mkdir(parents=True, exist_ok=True)
        (out_dir / "metrics.json").write_text(metrics_json(metrics))
        return metrics

    def picture_view(self, loops: list[np.ndarray]) -> MeshView | None:
        """The view of this model's mesh pictures (``eval.plots.mesh_view``); None frames each picture on
        its own mesh and Γ. Kinds whose pictures are compared with another (a reconstruction beside its
        target) return one view for both."""
        return None

    def summary(self, metrics: dict[str, Any]) -> str | None:
        """One sentence on what the final evaluation found, for the log (None: the metrics speak for themselves)."""
        return None

    def write_mesh(self, out_dir: str | Path, result: Any, loops: list[np.ndarray], title: str,
                   export: trimesh.Trimesh | None = None) -> dict[str, Any]:
        """``mesh.ply`` and ``mesh.png`` (seen as ``picture_view`` says) of a meshing result (a
        ``MeshingResult`` or a mesh) with its boundary ``loops``. ``export``: the mesh to write instead (e.g.
        in the input's coordinates). → its summary (``eval.metrics.mesh_summary``)."""
        out_dir = Path(out_dir)
        mesh = getattr(result, "mesh", result)
        write_mesh(export if export is not None else mesh, out_dir / "mesh.ply")
        plot_mesh(mesh, loops, out_dir / "mesh.png", title=title, view=self.picture_view(loops))
        return mesh_summary(result, loops)
