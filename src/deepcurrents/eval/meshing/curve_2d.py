"""``extract_curve_2d``: the curve of a 2D current (paper Fig. 3), the 2D analogue of the level-set method."""

from __future__ import annotations

import numpy as np
import torch
from skimage.measure import find_contours

from deepcurrents.eval.device import device_of
from deepcurrents.eval.meshing.level_set import aligned_with_grad_f


@torch.no_grad()
def extract_curve_2d(
    current, resolution: int = 256, delta: float = 5e-3, boundary_tube: float = 0.03, min_alignment: float = 0.5,
    chunk_size: int = 1 << 16,
) -> list[np.ndarray]:
    """The curve of a 2D current: the level set f = s (s = mean of f near the boundary points), kept where
    |ω| ≥ δ and cos(ω, ∇f) ≥ ``min_alignment`` (``level_set.aligned_with_grad_f``), cut at distance τ
    from the points and joined to them by straight segments.

    Returns a list of polylines, each (K, 2).
    """
    dev = device_of(current)
    axis = np.linspace(-1.0, 1.0, resolution + 1)
    h = axis[1] - axis[0]
    grid = np.stack(np.meshgrid(axis, axis, indexing="ij"), -1).reshape(-1, 2)
    f = current.evaluate(torch.as_tensor(grid, dtype=torch.float32, device=dev), chunk_size, omega=False)
    vol = f.cpu().numpy().reshape(len(axis), len(axis))
    poles = current.poles.cpu().double().numpy()
    tube = max(boundary_tube, 1.5 * h)
    ring = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    around = (poles[:, None, :] + 0.5 * tube * np.stack([np.cos(ring), np.sin(ring)], -1)).reshape(-1, 2)
    level = float(current.evaluate(torch.as_tensor(around, dtype=torch.float32, device=dev), omega=False).mean())
    curves = []
    for contour in find_contours(vol, level):
        pts = contour * h - 1.0
        dist = np.linalg.norm(pts[:, None] - poles[None], axis=-1).min(1)
        mid = 0.5 * (pts[1:] + pts[:-1])
        mid_t = torch.as_tensor(mid, dtype=torch.float32, device=dev)
        _, omega = current.evaluate(mid_t)
        # as in 3D: on the curve the current flows along ∇f; on the complementary level curve it does not
        carries = ((omega.norm(dim=-1) >= delta) & aligned_with_grad_f(current, mid_t, omega, min_alignment))
        good = carries.cpu().numpy() & (dist[1:] >= tube) & (dist[:-1] >= tube)
        # split into runs of good segments
        idx = np.flatnonzero(good)
        if len(idx) == 0:
            continue
        runs = np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1)
        for run in runs:
            piece = pts[run[0]: run[-1] + 2]
            joined = 0
            for end in (0, -1):  # join ends that stopped at the tube to their pole
                d = np.linalg.norm(poles - piece[end], axis=1)
                if d.min() < 1.5 * tube:
                    p = poles[d.argmin()][None]
                    piece = np.concatenate([p, piece]) if end == 0 else np.concatenate([piece, p])
                    joined += 1
            if joined:  # the current's curve ends on the boundary points; loose pieces are level-set debris
                curves.append(piece)
    return curves
