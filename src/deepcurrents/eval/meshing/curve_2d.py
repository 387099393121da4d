"""``extract_curve_2d``: the curve of a 2D current (paper Fig. 3).

Two methods, as in 3D (``meshing.phase``, ``meshing.level_set``):

- "phase" (default): α = ∇A with A = Σ_j s_j angle(x − p_j) (``geometry.biot_savart_2d``), so ω = s∇(f/s + A)
  and the phase φ = f/s + A (s = alpha_scale; A modulo 2π, which e^{iφ} does not see) is constant off the
  curve and turns once across it. With θ the off-curve value (the circular mean over the grid), the curve
  is the zero set of sin(φ − θ) where cos(φ − θ) < 0: a place where f keeps only a partial jump (a fraction
  of a turn) is not the curve, however large |ω| is there.
- "level_set": the paper's f = s (s = mean of f near the points), kept where |ω| ≥ δ and ω flows along ∇f.
  A partial jump of f whose level crosses s passes both filters (``minimal_2d preset=cpu``: the outer rays
  beyond the two points, 0.15–0.25 of a turn, doubled the length).
"""

from __future__ import annotations

import numpy as np
import torch
from scipy.ndimage import map_coordinates
from skimage.measure import find_contours

from deepcurrents.eval.device import device_of, require_memory
from deepcurrents.eval.level_sets import reads_level_sets
from deepcurrents.eval.meshing.level_set import aligned_with_grad_f
from deepcurrents.eval.meshing.surface import NODE_BYTES
from deepcurrents.geometry import angle_2d

CURVE_METHODS = ("phase", "level_set")


def phase_2d(current, x: torch.Tensor, f: torch.Tensor) -> torch.Tensor:
    """φ = f/s + Σ_j s_j angle(x − p_j) at points x (N, 2) from f there (N,) → (N,) float64 (module docstring)."""
    return f.double() / current.alpha_scale + angle_2d(x.double(), current.poles, current.signs)


def good_runs(points: np.ndarray, good: np.ndarray) -> list[np.ndarray]:
    """The runs of consecutive good segments of a polyline as polylines. points (K, 2), good (K − 1,) bool for
    the segments points[i] → points[i + 1]. A closed polyline (first point = last) whose good run passes its
    start gives one piece, not two with loose ends at the start."""
    idx = np.flatnonzero(good)
    if len(idx) == 0:
        return []
    runs = np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1)
    pieces = [points[run[0]: run[-1] + 2] for run in runs]
    if len(runs) > 1 and np.array_equal(points[0], points[-1]) and runs[0][0] == 0 and runs[-1][-1] == len(good) - 1:
        pieces = [np.concatenate([pieces[-1], pieces[0][1:]]), *pieces[1:-1]]
    return pieces


def check_curve_grid(resolution: int, key: str = "resolution") -> None:
    """One sentence naming ``key`` when the (resolution + 1)² grid of a 2D current's curve cannot fit in the memory
    available here (``NODE_BYTES`` a node, as a mesh's; 100000 asked numpy for 75 GiB after the training)."""
    require_memory(f"{key}={resolution}", NODE_BYTES * (int(resolution) + 1) ** 2,
                   f"a {resolution + 1}×{resolution + 1} grid, ")


@torch.no_grad()
@reads_level_sets
def extract_curve_2d(
    current, resolution: int = 256, delta: float = 5e-3, boundary_tube: float = 0.03, min_alignment: float = 0.5,
    method: str = "phase", chunk_size: int = 1 << 16,
) -> list[np.ndarray]:
    """The curve of a 2D current (module docstring: ``method`` "phase" or the paper's "level_set"), kept where
    |ω| ≥ δ (and, for the level set, cos(ω, ∇f) ≥ ``min_alignment``), cut at distance τ from the points and
    joined to them by straight segments; pieces that reach no point are dropped.

    Returns a list of polylines, each (K, 2).
    """
    if method not in CURVE_METHODS:
        raise ValueError(f"method={method!r} must be one of {CURVE_METHODS}.")
    check_curve_grid(resolution)
    dev = device_of(current)
    axis = np.linspace(-1.0, 1.0, resolution + 1)
    h = axis[1] - axis[0]
    grid = np.stack(np.meshgrid(axis, axis, indexing="ij"), -1).reshape(-1, 2)
    grid_t = torch.as_tensor(grid, dtype=torch.float32, device=dev)
    f = current.evaluate(grid_t, chunk_size, omega=False)
    poles = current.poles.cpu().double().numpy()
    tube = max(boundary_tube, 1.5 * h)
    if method == "phase":
        phase = phase_2d(current, grid_t, f)
        theta = float(torch.angle(torch.exp(1j * phase).mean()))  # off the curve, where most of the grid is
        rel = (phase - theta).cpu().numpy().reshape(len(axis), len(axis))
        vol, level, side = np.sin(rel), 0.0, np.cos(rel)
    else:
        vol = f.cpu().numpy().reshape(len(axis), len(axis))
        ring = np.linspace(0, 2 * np.pi, 64, endpoint=False)
        around = (poles[:, None, :] + 0.5 * tube * np.stack([np.cos(ring), np.sin(ring)], -1)).reshape(-1, 2)
        level = float(current.evaluate(torch.as_tensor(around, dtype=torch.float32, device=dev), omega=False).mean())
    curves = []
    for contour in find_contours(vol, level):
        pts = contour * h - 1.0
        dist = np.linalg.norm(pts[:, None] - poles[None], axis=-1).min(1)
        good = (dist[1:] >= tube) & (dist[:-1] >= tube)
        if method == "phase":
            # sin(φ − θ) also vanishes off the curve (φ ≈ θ): keep where φ is opposite θ; judged on the grid
            # first, so the many contours around θ cost no network pass
            good &= map_coordinates(side, (0.5 * (contour[1:] + contour[:-1])).T, order=1) < 0
        if not good.any():
            continue
        mid_t = torch.as_tensor(0.5 * (pts[1:] + pts[:-1]), dtype=torch.float32, device=dev)
        _, omega = current.evaluate(mid_t)
        carries = omega.norm(dim=-1) >= delta
        if method == "level_set":
            # as in 3D: on the curve the current flows along ∇f; on the complementary level curve it does not
            carries &= aligned_with_grad_f(current, mid_t, omega, min_alignment)
        good &= carries.cpu().numpy()
        for piece in good_runs(pts, good):
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
