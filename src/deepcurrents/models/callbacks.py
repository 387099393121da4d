"""Lightning callbacks: pictures of the current while it trains, and the final media of a run.

``MediaCallback`` renders the current every ``every_n_steps`` steps (3D: a volume render, paper style;
2D: Fig. 3's plot) into ``<run>/media/`` and, with a W&B logger, as images on the dashboard. After the
final evaluation (``train.py`` calls :meth:`MediaCallback.on_final_evaluation`) it writes ``render.png``
and, with W&B, logs that picture, the final mesh as a 3D object and the metrics as a table.
Without a logger or with ``logger=csv`` the files in the run directory are the record.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

import lightning as L
import numpy as np
import torch
from lightning.pytorch.callbacks import RichProgressBar
from lightning.pytorch.callbacks.progress.rich_progress import _RICH_AVAILABLE

from deepcurrents.errors import positive_int
from deepcurrents.eval.plots import figure_pixels
from deepcurrents.eval.render import (
    DensitySettings,
    fit_camera,
    proposal_grid,
    render_current,
    render_current_2d,
    save_image,
)
from deepcurrents.models.loading import current_to_view

log = logging.getLogger(__name__)


def _wandb_loggers(trainer: L.Trainer) -> list:
    from lightning.pytorch.loggers import WandbLogger

    return [lg for lg in trainer.loggers if isinstance(lg, WandbLogger)]


class StepProgressBar(RichProgressBar):
    """Lightning's rich progress bar, its task named "Training" instead of "Epoch 0/-2": a run here is one epoch
    of ``max_steps`` batches with ``max_epochs=-1``, which the stock bar prints as its last epoch, -2."""

    def _get_train_description(self, current_epoch: int) -> str:
        return f"{'Training':{len(self.validation_description)}}"


def progress_bar() -> L.Callback | None:
    """The run's progress bar: a ``StepProgressBar``, or None where rich is missing (Lightning's tqdm bar then
    says "Epoch 0", which reads right)."""
    return StepProgressBar() if _RICH_AVAILABLE else None


class MediaCallback(L.Callback):
    """Renders of the current during and after training.

    Args:
        every_n_steps: a render every this many training steps (0: none during training).
        final: render (and log) the final current after the final evaluation.
        size: image side in pixels; samples: ω samples per ray; grid: proposal grid resolution.
        azimuth, elevation: the camera's angles (degrees); it is fitted to the current's support.
        gain, floor: opacity settings (eval.render.DensitySettings).
    """

    def __init__(self, every_n_steps: int = 0, final: bool = True, size: int = 160, samples: int = 40,
                 grid: int = 40, azimuth: float = 35.0, elevation: float = 25.0, gain: float = 3.0,
                 floor: float = 2.5e-3):
        super().__init__()
        checks = (("every_n_steps", every_n_steps, 0), ("size", size, 1), ("samples", samples, 2),
                  ("grid", grid, 4))
        for name, value, low in checks:
            positive_int(f"callbacks.media.{name}", value, low)
        self.every_n_steps, self.final = every_n_steps, final
        self.size, self.samples, self.grid = size, samples, grid
        self.azimuth, self.elevation = azimuth, elevation
        self.settings = DensitySettings(gain=gain, floor=floor)

    # ------------------------------------------------------------------------------------------ render
    @torch.no_grad()
    def render(self, pl_module: L.LightningModule, path: Path | None = None,
               trainer: L.Trainer | None = None) -> np.ndarray | None:
        """A picture of the module's current → (H, W, 3) uint8 (also written to ``path``), None if there
        is nothing to look at. 2D: Fig. 3 with the metric's ellipses when the module or the trainer's
        DataModule has a ``metric_fn``."""
        try:
            current = current_to_view(pl_module)
        except ValueError:
            return None
        if current.dim == 2:
            metric_fn = getattr(pl_module, "metric_fn", None)
            if metric_fn is None and trainer is not None:
                metric_fn = getattr(trainer.datamodule, "metric_fn", None)
            fig = render_current_2d(current, None, metric_fn=metric_fn if callable(metric_fn) else None,
                                    show_alpha=not callable(metric_fn))
            image = np.ascontiguousarray(figure_pixels(fig)[..., :3])
        else:
            grid = proposal_grid(current, self.grid, self.settings)
            camera = fit_camera(grid.framing_points(), self.azimuth, self.elevation, width=self.size,
                                height=self.size)
            image = render_current(current, camera, samples=self.samples, grid=grid, settings=self.settings)
            image = image.over()
        if path is not None:
            save_image(image, path)
        return image

    # ------------------------------------------------------------------------------------------- hooks
    def on_train_batch_end(self, trainer: L.Trainer, pl_module: L.LightningModule, outputs: Any,
                           batch: Any, batch_idx: int) -> None:
        step = trainer.global_step
        if not self.every_n_steps or step == 0 or step % self.every_n_steps or not trainer.is_global_zero:
            return
        start = time.perf_counter()
        path = Path(trainer.default_root_dir) / "media" / f"render_step{step:07d}.png"
        image = self.render(pl_module, path, trainer)
        if image is None:
            return
        for lg in _wandb_loggers(trainer):
            lg.log_image(key="media/render", images=[image], step=step)
        log.info("media: rendered step %d in %.1f s", step, time.perf_counter() - start)

    def on_final_evaluation(self, trainer: L.Trainer, pl_module: L.LightningModule,
                            metrics: dict[str, Any], out_dir: str | Path) -> None:
        """Called by the train entry point after ``final_evaluation`` wrote metrics.json (and mesh.ply)."""
        if not self.final or not trainer.is_global_zero:
            return
        out_dir = Path(out_dir)
        image = self.render(pl_module, out_dir / "render.png", trainer)
        loggers = _wandb_loggers(trainer)
        if not loggers:
            return
        import trimesh
        import wandb

        step = int(pl_module.global_step)
        media: dict[str, Any] = {}
        if image is not None:
            media["media/final_render"] = wandb.Image(image)
        for name in ("mesh.png", "current.png"):  # pictures under their own keys: "final_mesh" is the 3D object
            if (out_dir / name).is_file():
                media[f"media/final_{Path(name).stem}_picture"] = wandb.Image(str(out_dir / name))
        if (out_dir / "mesh.ply").is_file():
            mesh = trimesh.load(out_dir / "mesh.ply", force="mesh", process=False)
            if len(mesh.faces):
                mesh.export(out_dir / "mesh.glb")  # W&B shows glb/obj/stl, not ply
                media["media/final_mesh"] = wandb.Object3D.from_file(str(out_dir / "mesh.glb"))
        # one row, one column per metric: each column keeps one type
        row = [v if isinstance(v, (int, float)) or v is None else str(v) for v in metrics.values()]
        media["media/final_metrics"] = wandb.Table(columns=list(metrics), data=[row])
        for lg in loggers:
            lg.experiment.log(media, step=step)
