"""The solid angle Ω_Γ and a current's phase on a meshing grid, exactly where needed and interpolated elsewhere.

The phase method needs φ = f/(2·alpha_scale) + Ω/2 at every grid node, and the network and Ω's closed form
(O(vertices) per node) there were most of the meshing time. Both are computed exactly on a coarse sub-grid
(every ``coarse``-th node); a coarse cell's nodes are then computed exactly only where that matters, and
e^{i·angle} is interpolated trilinearly on the others. For the phase (``grid_phase``) that is near Γ and in
the cells that the mesh's level θ + π can cross (``level_cells``): elsewhere no face of the mesh is made,
whatever the interpolation's error, so the mesh is the one the dense grid gives. For Ω alone
(``grid_solid_angle``) it is near Γ and where e^{iΩ/2} turns fast between corners (interpolation error about
h²|∇²Ω|/16, h the coarse spacing). The Newton steps that follow marching cubes evaluate the exact phase at
the mesh's vertices.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch
from scipy.spatial import cKDTree

from deepcurrents.geometry.biot_savart import solid_angle
from deepcurrents.geometry.polyline import closed_loop_segments, resample_polyline


def phase_from_f(current, x: torch.Tensor, f: torch.Tensor) -> torch.Tensor:
    """The phase φ = f/(2·alpha_scale) + Ω_Γ/2 (``meshing.phase``) at points x (P, 3) from f already evaluated
    there (P,) → (P,) float64.

    Ω is summed in float64: float32's millirad errors changed meshes where the phase lingers near the mesh's level
    (the Borromean rings; docs/notes/meshing.md)."""
    omega = solid_angle(x.double(), [lp.to(device=x.device, dtype=torch.float64) for lp in current.loops])
    return f.double() / (2.0 * current.alpha_scale) + 0.5 * omega


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

    def turning(values: np.ndarray, corners: list[tuple[slice, ...]]) -> np.ndarray:
        z = np.exp(1j * values[..., 0])
        cells = np.zeros(values[corners[0]].shape[:-1], dtype=bool)
        for i, a in enumerate(corners):
            for b in corners[i + 1:]:
                cells |= np.abs(np.angle(z[a] * np.conj(z[b]))) > max_turn
        return cells

    return 2.0 * banded_angle(points, shape, loops, exact, turning, coarse, near)


def grid_phase(current, points: torch.Tensor, shape: tuple[int, int, int], loops: list[np.ndarray],
               coarse: int = 4, near: float = 0.02, margin: float = 0.25,
               chunk_size: int = 1 << 14, info: dict | None = None) -> tuple[torch.Tensor, float]:
    """The phase φ = f/(2·alpha_scale) + Ω/2 of a 3D current (meshing.phase) at the nodes of a regular grid,
    modulo 2π, exact wherever the mesh is made and interpolated elsewhere.

    The mesh is the level φ ≡ θ + π (θ the off-surface phase), so only the coarse cells that this level can
    cross need exact values (``level_cells``), and those near Γ. A coarse cell elsewhere is interpolated
    (trilinearly in e^{iφ}): its corners' phases span less than π without reaching the level, so its
    interpolated values do not reach it either, and marching cubes finds no part of the mesh there, as on
    the dense grid (the same faces from the same values; tests/benchmarks/test_time_to_quality.py). Within the smeared
    jump of a partly trained current this skips the cells at the other levels, which the former test
    (corners' e^{iφ} differing by more than 0.25 rad) computed: 150k exact nodes instead of 319k of 1.05M
    for the trained ``make run`` trefoil. θ is the circular mean of φ over every node, as before; the cells
    are chosen with its value over the coarse nodes, which differs from it by less than the margin (5e-3 rad
    on a planar circle's thin grid, whose nodes are mostly in the current's smeared jump; 1e-4 on the
    trefoil; within 1.1e-4 of its value on the dense grid either way). ``info``: as ``banded_angle``'s, its
    "exact" f/(2·alpha_scale) at the nodes computed exactly.
    points: (G0·G1·G2, 3) → (φ (G0·G1·G2,) float64 modulo 2π, θ)."""
    two_a = 2.0 * current.alpha_scale

    def exact(x: torch.Tensor) -> torch.Tensor:
        parts = []
        for c in torch.split(x, chunk_size):
            f = current.evaluate(c, chunk_size, omega=False)
            parts.append(torch.stack([phase_from_f(current, c, f), f.double() / two_a], -1))
        return torch.cat(parts)

    def mark(values: np.ndarray, corners: list[tuple[slice, ...]]) -> np.ndarray:
        return level_cells(values, corners, off_surface_phase(values[..., 0]), margin)

    phase = banded_angle(points, shape, loops, exact, mark, coarse, near, info)
    return phase, off_surface_phase(phase.cpu().numpy())


def off_surface_phase(phase: np.ndarray) -> float:
    """θ, the circular mean of phases (any shape) sampled on a grid: a current's phase off its surface, where
    most nodes are."""
    return float(np.angle(np.exp(1j * phase).mean()))


def _wrap(angle: np.ndarray) -> np.ndarray:
    """An angle modulo 2π in [−π, π)."""
    return (angle + np.pi) % (2.0 * np.pi) - np.pi


def level_cells(values: np.ndarray, corners: list[tuple[slice, ...]], theta: float, margin: float) -> np.ndarray:
    """Coarse cells that the phase mesh's level θ + π can cross, from the phase at the cells' corners.

    values (C0, C1, C2, 2): φ and f/(2·alpha_scale) at the coarse nodes; corners: the 8 slices of it that
    give each cell's corners; θ: the off-surface phase. Between two corners φ changes by the change of
    f/(2·alpha_scale) (the network is continuous: a sheet thinner than the cell shows as a full turn) plus
    that of Ω/2 wrapped into [−π, π) (exact for corners of a cell that Γ does not pass through or near, which
    the caller computes anyway), so each cell has its corners' unwrapped phase interval [lo, hi]. It is
    marked when [lo − m, hi + m] holds the level, m = margin + (hi − lo)/4 (a curved level surface can bulge
    between corners, by more where φ turns fast), or when hi − lo ≥ π − margin (e^{iφ} interpolated over
    more than half a turn could reach any phase). → (C0 − 1, C1 − 1, C2 − 1) bool."""
    phase, f = values[..., 0], values[..., 1]
    half_omega = phase - f
    first = corners[0]
    rel = np.stack([f[c] - f[first] + _wrap(half_omega[c] - half_omega[first]) for c in corners])
    base = _wrap(phase[first] - theta - np.pi)
    lo, hi = base + rel.min(0), base + rel.max(0)
    span = hi - lo
    m = margin + 0.25 * span
    reaches = np.floor((hi + m) / (2.0 * np.pi)) >= np.ceil((lo - m) / (2.0 * np.pi))
    return reaches | (span >= np.pi - margin)


def banded_angle(points: torch.Tensor, shape: tuple[int, int, int], loops: list[np.ndarray],
                 exact: Callable[[torch.Tensor], torch.Tensor],
                 mark: Callable[[np.ndarray, list[tuple[slice, ...]]], np.ndarray], coarse: int,
                 near: float, info: dict | None = None) -> torch.Tensor:
    """An angle field on a grid from its exact values at a coarse sub-grid and in the coarse cells that
    need them (near Γ, and those ``mark`` picks), trilinear interpolation of e^{i·angle} elsewhere.
    ``exact(x)`` (N, 3) → (N, k): column 0 the angle, other columns what ``mark`` needs;
    ``mark(values (C0, C1, C2, k), corners)`` → (C0 − 1, C1 − 1, C2 − 1) bool, ``corners`` the 8 slices of
    the coarse nodes that give each cell's corners. → (G0·G1·G2,) float64 angle (mod 2π). ``info`` (a dict, if
    given) receives under "exact" the other columns of ``exact`` at every node where it was evaluated, NaN at the
    interpolated ones: (G0, G1, G2, k − 1) float64."""
    dev = points.device
    if coarse <= 1 or min(shape) < 3:
        values = exact(points)
        if info is not None:
            info["exact"] = values[:, 1:].double().cpu().numpy().reshape(*shape, -1)
        return values[:, 0]
    grid = points.reshape(*shape, 3)
    idx = [_coarse_index(n, coarse) for n in shape]
    sub = grid[idx[0]][:, idx[1]][:, :, idx[2]]
    values = exact(sub.reshape(-1, 3)).cpu().numpy().reshape(*(len(i) for i in idx), -1)
    cell_shape = tuple(len(i) - 1 for i in idx)
    corners = [tuple(slice(c, c + s) for c, s in zip(corner, cell_shape, strict=True))
               for corner in np.ndindex(2, 2, 2)]
    cells = mark(values, corners)
    # cells whose centre is within half a diagonal + ``near`` of Γ (at least half a cell, so that Γ does not
    # pass between two corners of an unmarked cell: their Ω/2 then differs by less than π, as mark assumes)
    # (distances to points of Γ at most h/4 apart, each within h/8 of the distance to Γ itself)
    spacing = float(coarse * (grid[1, 1, 1] - grid[0, 0, 0]).min())
    centres = 0.5 * (sub[:-1, :-1, :-1] + sub[1:, 1:, 1:]).reshape(-1, 3).double().cpu().numpy()
    reach = spacing * np.sqrt(3.0) / 2 + max(near, 0.5 * spacing)
    starts, ends, _ = closed_loop_segments(loops)
    dist, _ = cKDTree(resample_polyline(starts, ends, spacing / 4)).query(centres, distance_upper_bound=2 * reach)
    cells |= (dist - spacing / 8 < reach).reshape(cells.shape)
    # interpolate e^{i·angle} on every node, then replace the nodes of exact cells
    fine = np.exp(1j * values[..., 0])
    for axis, (n, i) in enumerate(zip(shape, idx, strict=True)):
        fine = _lerp_axis(fine, i, n, axis)
    mask = np.zeros(shape, dtype=bool)
    for c in np.argwhere(cells):
        mask[idx[0][c[0]]:idx[0][c[0] + 1] + 1, idx[1][c[1]]:idx[1][c[1] + 1] + 1,
             idx[2][c[2]]:idx[2][c[2] + 1] + 1] = True
    flat = torch.as_tensor(mask.reshape(-1), device=dev)
    out = torch.as_tensor(np.angle(fine).reshape(-1), dtype=torch.float64, device=dev)
    known = np.full((*shape, values.shape[-1] - 1), np.nan) if info is not None else None
    if known is not None:
        known[np.ix_(*idx)] = values[..., 1:]
    if bool(flat.any()):
        inside = exact(points[flat])
        out[flat] = inside[:, 0]
        if known is not None:
            known.reshape(-1, known.shape[-1])[mask.reshape(-1)] = inside[:, 1:].double().cpu().numpy()
    if info is not None:
        info["exact"] = known
    return out


def aliased_edges(phase: np.ndarray, half_f: np.ndarray) -> np.ndarray:
    """The grid edges across which the phase turns by more than half a turn, which e^{iφ} sampled at the two nodes
    shows turning the other way (a jump of the current only a few cells thick): marching cubes then puts the
    crossing on the off-surface side and the mesh loses the sheet there. The turn is unwrapped through f, which is
    continuous: Δφ = Δ(f/2a) + wrap(Δ(φ − f/2a)), the second term Ω/2's change (exact unless Γ passes between the
    nodes: callers leave out the edges near Γ). phase, half_f (G0, G1, G2): φ and f/(2·alpha_scale) at the nodes,
    NaN where unknown (no edge there). → (E, 2, 3) int: each aliased edge's two node indices."""
    out = []
    for axis in range(3):
        turn = np.diff(half_f, axis=axis) + _wrap(np.diff(phase - half_f, axis=axis))
        with np.errstate(invalid="ignore"):
            first = np.argwhere(np.abs(turn) > np.pi)
        second = first.copy()
        second[:, axis] += 1
        out.append(np.stack([first, second], 1))
    return np.concatenate(out)
