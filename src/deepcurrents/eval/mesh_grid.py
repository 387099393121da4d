"""A grid of mesh pictures in one image (families: training shapes, interpolations, paper Fig. 6)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import trimesh  # noqa: E402

from deepcurrents.eval.plots import plot_mesh  # noqa: E402


def plot_mesh_grid(
    meshes: Sequence[trimesh.Trimesh],
    loops: Sequence[Sequence[np.ndarray]] | None,
    path: str | Path,
    titles: Sequence[str] | None = None,
    ncols: int | None = None,
    size: float = 3.0,
    elev: float = 25.0,
    azim: float = 35.0,
) -> np.ndarray:
    """Draws each mesh with ``plot_mesh`` (normal colours, Γ in black) and tiles the pictures row by row,
    ``ncols`` per row (default: as square as possible). Writes a PNG at ``path``. → the image (H, W, 4)."""
    n = len(meshes)
    if n == 0:
        raise ValueError("plot_mesh_grid needs at least one mesh")
    ncols = ncols or int(np.ceil(np.sqrt(n)))
    tiles = []
    for i, mesh in enumerate(meshes):
        fig = plot_mesh(mesh, None if loops is None else list(loops[i]), None,
                        title=None if titles is None else titles[i], elev=elev, azim=azim, size=size)
        fig.canvas.draw()
        tiles.append(np.asarray(fig.canvas.buffer_rgba()).copy())
        plt.close(fig)
    h, w = tiles[0].shape[:2]
    nrows = int(np.ceil(n / ncols))
    image = np.full((nrows * h, ncols * w, 4), 255, dtype=np.uint8)
    for i, tile in enumerate(tiles):
        r, c = divmod(i, ncols)
        image[r * h:(r + 1) * h, c * w:(c + 1) * w] = tile[:h, :w]
    plt.imsave(path, image)
    return image
