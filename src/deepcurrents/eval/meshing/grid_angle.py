"""The solid angle Ω_Γ and a current's phase on a meshing grid, exactly where needed and interpolated elsewhere.

The phase method needs Ω at every grid node, and the closed form costs O(vertices) per node: for a
300-vertex curve on a 128³ grid it was about 90% of the meshing time. The phase only uses e^{iΩ/2}, which is
smooth everywhere off Γ (Ω jumps by 4π across its branch cut, which e^{iΩ/2} does not see), so it is computed
exactly on a coarse sub-grid (every ``coarse``-th node) and interpolated trilinearly on the others, except in
coarse cells near Γ or where e^{iΩ/2} turns fast between corners, which are computed exactly. The
interpolation error is about h²|∇²Ω|/16 (h the coarse spacing), small where |∇²Ω| ~ 1/r² is small, and the
Newton steps that follow marching cubes evaluate the exact phase at the mesh's vertices.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch
from scipy.ndimage import binary_dilation

from deepcurrents.geometry.biot_savart import solid_angle


def _coarse_index(n: int, step: int) -> np.ndarray:
    """Every step-th index of 0..n-1, always with the last. → (m,) int."""
    idx = np.arange(0, n, step)
    return idx if idx[-1] == n - 1 else np.append(idx, n - 1)


def _lerp_axis(values: np.ndarray, coarse: np.ndarray, n: int, axis: int) -> np.ndarray:
    """Linear interpolation along ``axis`` from the nodes ``coarse`` (sorted indices) to all n indices."""
    fine = np.arange(n)
    cell = np.clip(np.searchsorted(coarse, fine, side="right") - 1, 0, len(coarse) - 2)
    t = (fine - coarse[cell]) / (coarse[cell + 1] - coarse[cell])
    lo, hi = np.take(values, cell, axis=axis), np.take(values, cell + 1, axis=axis)
    shape = [1] * values.ndim
    shape[axis] = n
    t = t.reshape(shape)
    return lo * (1 - t) + hi * t


def grid_solid_angle(points: torch.Tensor, shape: tuple[int, int, int], loops: list[np.ndarray],
                     coarse: int = 4, near: float = 0.05, max_turn: float = 0.25,
                     chunk_size: int = 1 << 14) -> torch.Tensor:
    """Ω_Γ (modulo 4π) at the nodes of a regular grid, exact near Γ, interpolated elsewhere.

    Args:
        points: (G0·G1·G2, 3) grid nodes, row-major in ``shape`` (as eval.meshing's grids).
        loops: Γ's loops, list of (M_i, 3).
        coarse: the sub-grid's step in nodes (1: every node exact).
        near: coarse cells within this distance of Γ are computed exactly.
        max_turn: coarse cells whose corners' e^{iΩ/2} differ by more than this angle (radians) too.
    Returns:
        (G0·G1·G2,) float64 on points' device, equal to solid_angle(points, loops) modulo 4π up to the
        interpolation error off the exact cells.
    """
    torch_loops = [torch.as_tensor(lp, dtype=torch.float64, device=points.device) for lp in loops]

    def exact(x: torch.Tensor) -> torch.Tensor:
        return torch.cat([solid_angle(c.double(), torch_loops) for c in torch.split(x, chunk_size)])[:, None] / 2

    return 2.0 * banded_angle(points, shape, loops, exact, coarse, near, max_turn)


def grid_phase(current, points: torch.Tensor, shape: tuple[int, int, int], loops: list[np.ndarray],
               coarse: int = 4, near: float = 0.05, max_turn: float = 0.25, max_jump: float = 0.5,
               chunk_size: int = 1 << 14) -> torch.Tensor:
    """The phase φ = f/(2·alpha_scale) + Ω/2 of a 3D current (meshing.phase) at the nodes of a regular grid,
    modulo 2π: exact near Γ, where e^{iφ} turns fast, and in coarse cells where f/(2·alpha_scale) changes by
    more than ``max_jump`` between corners (a sheet of the surface crosses the cell: f jumps there, while
    e^{iφ} may look the same on both sides); interpolated from the coarse nodes elsewhere, where f and Ω
    are both smooth. Network and solid angle are then evaluated at a fraction of the nodes.
    points: (G0·G1·G2, 3) → (G0·G1·G2,) float64."""
    torch_loops = [torch.as_tensor(lp, dtype=torch.float64, device=points.device) for lp in loops]
    two_a = 2.0 * current.alpha_scale

    def exact(x: torch.Tensor) -> torch.Tensor:
        parts = []
        for c in torch.split(x, chunk_size):
            f = current.evaluate(c, chunk_size, omega=False).double() / two_a
            parts.append(torch.stack([f + 0.5 * solid_angle(c.double(), torch_loops), f], -1))
        return torch.cat(parts)

    return banded_angle(points, shape, loops, exact, coarse, near, max_turn, max_jump)


def banded_angle(points: torch.Tensor, shape: tuple[int, int, int], loops: list[np.ndarray],
                 exact: Callable[[torch.Tensor], torch.Tensor], coarse: int, near: float, max_turn: float,
                 max_jump: float = float("inf")) -> torch.Tensor:
    """An angle field on a grid from its exact values at a coarse sub-grid and in the coarse cells that
    need them (near Γ, fast turning, or a jump of the other columns), trilinear interpolation of e^{i·angle}
    elsewhere. ``exact(x)`` (N, 3) → (N, k): column 0 the angle, columns 1.. unwrapped quantities whose
    range over a cell's corners above ``max_jump`` marks it. → (G0·G1·G2,) float64 angle (mod 2π)."""
    dev = points.device
    if coarse <= 1 or min(shape) < 3:
        return exact(points)[:, 0]
    grid = points.reshape(*shape, 3)
    idx = [_coarse_index(n, coarse) for n in shape]
    sub = grid[idx[0]][:, idx[1]][:, :, idx[2]]
    values = exact(sub.reshape(-1, 3)).cpu().numpy().reshape(*(len(i) for i in idx), -1)
    z = np.exp(1j * values[..., 0])  # continuous wherever the angle is smooth modulo 2π
    cells = np.zeros(tuple(len(i) - 1 for i in idx), dtype=bool)
    corners = [tuple(slice(c, c + s) for c, s in zip(corner, cells.shape, strict=True))
               for corner in np.ndindex(2, 2, 2)]
    for i, a in enumerate(corners):
        for b in corners[i + 1:]:
            cells |= np.abs(np.angle(z[a] * np.conj(z[b]))) > max_turn
    if values.shape[-1] > 1:
        stacked = np.stack([values[c][..., 1:] for c in corners])
        cells |= (stacked.max(0) - stacked.min(0)).max(-1) > max_jump
    origin = grid[0, 0, 0].cpu().numpy().astype(np.float64)
    spacing = (grid[1, 1, 1].cpu().numpy().astype(np.float64) - origin)
    samples = np.concatenate([_densify(lp, float(spacing.min())) for lp in loops])
    node = np.rint((samples - origin) / spacing).astype(int)
    coarse_cell = np.stack([np.clip(np.searchsorted(i, node[:, a], side="right") - 1, 0, len(i) - 2)
                            for a, i in enumerate(idx)], -1)
    near_gamma = np.zeros_like(cells)
    near_gamma[tuple(coarse_cell.T)] = True
    reach = max(1, int(np.ceil(near / (coarse * float(spacing.min())))))
    cells |= binary_dilation(near_gamma, iterations=reach)
    # interpolate e^{i·angle} on every node, then replace the nodes of exact cells
    fine = z
    for axis, (n, i) in enumerate(zip(shape, idx, strict=True)):
        fine = _lerp_axis(fine, i, n, axis)
    mask = np.zeros(shape, dtype=bool)
    for c in np.argwhere(cells):
        mask[idx[0][c[0]]:idx[0][c[0] + 1] + 1, idx[1][c[1]]:idx[1][c[1] + 1] + 1,
             idx[2][c[2]]:idx[2][c[2] + 1] + 1] = True
    flat = torch.as_tensor(mask.reshape(-1), device=dev)
    out = torch.as_tensor(np.angle(fine).reshape(-1), dtype=torch.float64, device=dev)
    if bool(flat.any()):
        out[flat] = exact(points[flat])[:, 0]
    return out


def _densify(loop: np.ndarray, spacing: float) -> np.ndarray:
    """Points along a closed polyline no farther apart than ``spacing``. (M, 3) → (K, 3)."""
    loop = np.asarray(loop, dtype=np.float64)
    nxt = np.roll(loop, -1, axis=0)
    out = []
    for a, b in zip(loop, nxt, strict=True):
        k = max(1, int(np.ceil(np.linalg.norm(b - a) / spacing)))
        out.append(a + (b - a) * (np.arange(k)[:, None] / k))
    return np.concatenate(out)
