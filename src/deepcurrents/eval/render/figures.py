"""Pictures drawn with matplotlib for the apps and callbacks: an extracted mesh seen from a volume camera's
angles, and a 2D current (paper Fig. 3)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from deepcurrents.eval.device import device_of
from deepcurrents.eval.meshing import extract_curve_2d
from deepcurrents.eval.plots import figure_pixels, plot_current_2d, plot_mesh
from deepcurrents.eval.render.camera import Camera


def render_mesh(mesh, loops: Sequence[np.ndarray] | None = None, camera: Camera | None = None,
                path: str | Path | None = None, title: str | None = None) -> np.ndarray:
    """A plain shaded mesh picture (``plots.plot_mesh``) seen from the camera's angles → (H, W, 3) uint8.

    matplotlib's 3D view is orthographic-ish and fits the data: only the angles and the size are used.
    """
    camera = camera or Camera()
    size = max(camera.width, camera.height) / 120.0
    fig = plot_mesh(mesh, list(loops or []), None, title=title, elev=camera.elevation, azim=camera.azimuth,
                    size=size)
    return np.ascontiguousarray(figure_pixels(fig, path)[..., :3])


@torch.no_grad()
def render_current_2d(current, path: str | Path | None = None, curves: list[np.ndarray] | None = None,
                      metric_fn=None, show_alpha: bool = True, resolution: int = 201, arrows: int = 21,
                      title: str | None = None, chunk_size: int = 1 << 15):
    """Paper Fig. 3 for a 2D current: f as a density plot, α as arrows (``show_alpha``), the metric as
    ellipses (when ``metric_fn(x (N, 2)) -> B (N, 2, 2) or weights (N,)`` is given), the curve and the
    boundary points (red where the curve ends, blue where it starts).

    ``curves`` default: ``eval.meshing.extract_curve_2d(current)``. → the matplotlib Figure (closed if saved).
    """
    dev = device_of(current)
    g = torch.linspace(-1, 1, resolution, device=dev)
    grid = torch.stack(torch.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
    f = current.evaluate(grid, chunk_size=chunk_size, omega=False).reshape(resolution, resolution)
    f = f.cpu().numpy()
    c = torch.linspace(-1, 1, arrows + 2, device=dev)[1:-1]  # interior nodes: α is singular at no edge
    coarse = torch.stack(torch.meshgrid(c, c, indexing="ij"), -1).reshape(-1, 2)
    alpha = current.alpha(coarse).reshape(arrows, arrows, 2).cpu().numpy() if show_alpha else None
    metric = None
    if metric_fn is not None:
        b = torch.as_tensor(metric_fn(coarse))
        if b.dim() == 1:  # scalar weights w: B = w I
            b = b[:, None, None] * torch.eye(2, dtype=b.dtype, device=b.device)
        metric = b.reshape(arrows, arrows, 2, 2).detach().cpu().double().numpy()
    if curves is None:
        curves = extract_curve_2d(current)
    return plot_current_2d(f, alpha, curves, current.poles.cpu().numpy(), current.signs.cpu().numpy(), path,
                           title=title, metric_grid=metric, grid_extent=float(c[-1]))
