"""Metrics of a current: the extraction-free mass bound, mesh area, boundary adherence."""

from __future__ import annotations

import json
import math
from typing import Any

import igl
import numpy as np
import torch
import trimesh

from deepcurrents.eval.device import device_of
from deepcurrents.geometry.biot_savart import loop_segments
from deepcurrents.geometry.polyline import (
    closed_loop_segments,
    polyline_hausdorff,
    project_to_segments,
    sample_tube,
    segment_distance,
    tube_density,
)
from deepcurrents.geometry.topology import border_edges


def metrics_json(value: Any) -> str:
    """``value`` (a dict of metrics, nested dicts and lists) as indented, strict JSON: NaN and infinities are
    written as null (Python's ``NaN`` token is not JSON, and other tools refuse a file that holds it)."""
    def clean(v: Any) -> Any:
        if isinstance(v, float) and not math.isfinite(v):
            return None
        if isinstance(v, dict):
            return {k: clean(x) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [clean(x) for x in v]
        return v
    return json.dumps(clean(value), indent=2, allow_nan=False)


def jump(dim: int) -> float:
    """The jump of the (solid) angle across the optimal surface: 4π in 3D, 2π in 2D."""
    return 4.0 * math.pi if dim == 3 else 2.0 * math.pi


def mass_to_area(mass: float, dim: int, alpha_scale: float) -> float:
    """mass_area = E|ω| · vol(U) / (jump · alpha_scale): the optimal current is jump · alpha_scale · n δ_Σ
    (the (solid) angle jumps by 4π across any surface spanning Γ, 2π in 2D), so for any current E|ω| is at
    least jump · alpha_scale · Area(Σ_min) / vol(U), and mass_area is an upper bound of the minimal area."""
    return mass * 2.0**dim / (jump(dim) * alpha_scale)


def _strata(n: int, dim: int) -> int:
    """K, the largest even number with K^dim ≤ n: the side of the stratified grid of a chunk of n samples."""
    return int(math.floor(n ** (1.0 / dim) + 1e-9)) // 2 * 2


def _cell_corners(k: int, dim: int) -> torch.Tensor:
    """Integer corners of the k^dim cells, row-major (neighbouring indices: neighbouring cells). → (k^dim, dim)"""
    return torch.stack(torch.meshgrid(*[torch.arange(k)] * dim, indexing="ij"), -1).reshape(-1, dim)


def stratified_uniform(n: int, dim: int, generator: torch.Generator) -> torch.Tensor:
    """n points of U = [-1, 1]^dim, each uniform over U: one in each cell of a K^dim grid (K the largest even
    number with K^dim ≤ n, cells in row-major order, so that samples 2j and 2j + 1 lie in neighbouring cells)
    and the n − K^dim others uniform over U. → (n, dim) float32 on the CPU."""
    u = torch.rand(n, dim, generator=generator)
    k = _strata(n, dim)
    if k >= 2:
        cells = _cell_corners(k, dim)
        u[: len(cells)] = (cells + u[: len(cells)]) / k
    return u * 2.0 - 1.0


def paired_square_sum(values: torch.Tensor) -> float:
    """Σ_j (y_2j − y_2j+1)² over consecutive pairs, scaled to all of values (N,) (odd N: one unpaired): for
    samples in neighbouring strata (``stratified_uniform``) it estimates n² times the variance of their mean
    (collapsed strata: conservative by the squared differences of neighbouring strata's means), for
    independent samples too (2σ² per pair). values (..., N): the sum of that over the leading rows."""
    n = values.shape[-1]
    pairs = n // 2
    if pairs == 0:
        return 0.0
    diff = values[..., 0 : 2 * pairs : 2] - values[..., 1 : 2 * pairs : 2]
    return float((diff * diff).sum()) * n / (2 * pairs)


def boundary_segments(current) -> tuple[torch.Tensor, torch.Tensor] | None:
    """Γ of a current as segments (starts (S, d), ends (S, d)), float64 on the CPU: its closed loops (3D,
    ``current.loops``) or its poles as points (2D, ``current.poles``); None if it has neither."""
    if current.dim == 3 and getattr(current, "loops", None):
        starts, ends = loop_segments([torch.as_tensor(lp).detach().cpu().double() for lp in current.loops])
        return starts, ends
    poles = getattr(current, "poles", None)
    if current.dim == 2 and poles is not None:
        poles = poles.detach().cpu().double()
        return poles, poles
    return None


def cells_near_boundary(k: int, dim: int, segments: tuple[torch.Tensor, torch.Tensor],
                        reach: float = 2.0) -> torch.Tensor:
    """Which cells of the k^dim grid over U have their centre within ``reach`` cell sides of Γ (with 2: every
    cell Γ passes through, whose centre is at most √d/2 sides from it, and a layer or two around them).
    → (k^dim,) bool."""
    centres = ((_cell_corners(k, dim).double() + 0.5) / k) * 2.0 - 1.0
    if dim == 3:  # an AABB tree on Γ's segments: O((N + S) log S)
        starts, ends = (np.asarray(t.detach().cpu().double()) for t in segments)
        return torch.from_numpy(segment_distance(centres.numpy(), starts, ends) < reach * 2.0 / k)
    return project_to_segments(centres, *segments).distance < reach * 2.0 / k


def cells_containing(k: int, dim: int, points: torch.Tensor) -> torch.Tensor:
    """Which cells of the k^dim grid over U hold at least one of ``points`` (P, dim). → (k^dim,) bool."""
    index = ((points.detach().cpu().double() + 1.0) * 0.5 * k).floor().long().clamp(0, k - 1)
    flat = torch.zeros((), dtype=torch.long)
    for axis in range(dim):  # row-major, as _cell_corners orders the cells
        flat = flat * k + index[:, axis]
    mask = torch.zeros(k**dim, dtype=torch.bool)
    mask[flat] = True
    return mask


@torch.no_grad()
def mass_estimate(current, num_samples: int = 1 << 20, seed: int = 0, chunk_size: int = 1 << 15,
                  metric_fn=None, rel_stderr: float | None = None, min_samples: int = 1 << 16,
                  info: dict | None = None, refine: int = 1,
                  refine_points: torch.Tensor | None = None, tube_radius: float = 0.0,
                  tube_fraction: float = 0.125) -> tuple[float, float]:
    """Monte Carlo E_x |B_x ω(x)| over U = [-1, 1]^d and its standard error, in chunks (bounded memory).

    Each chunk is stratified (``stratified_uniform``: one sample per cell of a k^d grid): every sample is uniform
    over U and the mean is unbiased as with independent samples, but the variance between cells is gone. The
    standard error is the collapsed-strata estimate (``paired_square_sum``) over the cells' values.
    ``refine`` > 1: the cells near Γ (``cells_near_boundary``) are split into refine^d sub-cells with one uniform
    sample each; the cell's value is their mean and its variance is estimated from pairs of neighbouring
    sub-cells. Near Γ, |ω| ≈ alpha_scale·|α| ∼ 1/r has no finite variance and dominates the estimate's; every cell
    still weighs its volume and every sample is uniform within its (sub-)cell, so the estimate stays unbiased.
    ``refine_points`` (P, d): the cells holding any of them are refined as well (e.g. the final mesh's vertices:
    a sharpened current's |ω| lives in a thin shell around its mesh; ``evaluation.mass_refine_mesh``).
    ``tube_radius`` > 0 (3D loops): the tube T of points within it of Γ's segments (``tube_density``) is
    integrated apart, by ``tube_fraction`` × n samples a chunk drawn with density q ∝ 1/r about Γ
    (``sample_tube``), each weighing |ω|/q, while the stratified samples that fall in T count 0: |ω|·r stays
    bounded next to Γ, so the tube's part has a finite variance where uniform samples' diverges.
    ``metric_fn(x) -> B`` (None for B = I) lets reconstruction evaluate its weighted mass the same way.
    ``rel_stderr``: stop early, once at least ``min_samples`` are drawn and stderr / mean ≤ rel_stderr
    (``num_samples`` is then the most it draws). Samples count cells (the points a plain stratified estimate
    would draw); ``info`` (a dict, if given) receives their number under "samples" and the points evaluated
    (refined cells' sub-samples included) under "evaluations". The variance study behind these choices:
    docs/notes/meshing.md, "The mass bound's estimator".
    """
    if refine < 1:
        raise ValueError(f"refine={refine} must be at least 1.")
    dim, dev = current.dim, device_of(current)
    gen = torch.Generator(device="cpu").manual_seed(seed)
    boundary = boundary_segments(current) if refine > 1 or tube_radius > 0 else None
    segments = boundary if refine > 1 else None
    points = refine_points if refine > 1 and refine_points is not None and len(refine_points) else None
    refined: dict[int, tuple | None] = {}  # per grid side k, found once: (the refined cells, their corners)
    tube = None  # Γ's segments when the tube about them is integrated apart (3D loops of positive length)
    if tube_radius > 0 and dim == 3 and boundary is not None:
        tube = boundary if float((boundary[1] - boundary[0]).norm(dim=-1).sum()) > 0 else None

    def norm_of_omega(x: torch.Tensor) -> torch.Tensor:
        x = x.to(dev)
        _, omega = current(x, create_graph=False)
        if metric_fn is not None:
            from deepcurrents.losses import apply_metric

            omega = apply_metric(omega, metric_fn(x))
        return omega.norm(dim=-1).double()

    total, paired, done, evaluated = 0.0, 0.0, 0, 0
    while done < num_samples:
        n = min(chunk_size, num_samples - done)
        k = _strata(n, dim)
        if (segments is not None or points is not None) and k >= 2 and k not in refined:
            refined[k] = _cells_to_refine(k, dim, segments, points)
        x, near = _chunk_points(n, dim, gen, refined.get(k), refine)
        m = norm_of_omega(x)
        evaluated += len(m)
        if tube is not None:
            m = m.masked_fill(tube_density(x, *tube, tube_radius).to(m.device) > 0, 0.0)
            tube_total, tube_paired, tube_evaluated = _tube_part(norm_of_omega, tube, tube_radius, n, tube_fraction,
                                                                 dim, x.dtype, gen)
            total, paired, evaluated = total + tube_total, paired + tube_paired, evaluated + tube_evaluated
        chunk_total, chunk_paired = _cells_part(m, n, near)
        total, paired, done = total + chunk_total, paired + chunk_paired, done + n
        if rel_stderr is not None and done >= min_samples and done < num_samples:
            if math.sqrt(paired) / done <= rel_stderr * abs(total / done):
                break
    if info is not None:
        info["samples"] = done
        info["evaluations"] = evaluated
    return total / done, math.sqrt(paired) / done


def _cells_to_refine(k: int, dim: int, segments: tuple | None, points: torch.Tensor | None) -> tuple | None:
    """The cells of the k^d grid to refine: near Γ's ``segments`` and holding any of ``points``.
    → (their indices (C,), their integer corners (C, d)), or None when there are none."""
    near = torch.zeros(k**dim, dtype=torch.bool)
    if segments is not None:
        near |= cells_near_boundary(k, dim, segments)
    if points is not None:
        near |= cells_containing(k, dim, points)
    near = near.nonzero().squeeze(1)
    return (near, _cell_corners(k, dim)[near]) if len(near) else None


def _chunk_points(n: int, dim: int, gen: torch.Generator, refined: tuple | None,
                  refine: int) -> tuple[torch.Tensor, torch.Tensor | None]:
    """One chunk's points: n stratified samples, the refined cells' own replaced by refine^d sub-cell samples
    each, placed last. → (points (N, d), the refined cells' indices or None)."""
    x = stratified_uniform(n, dim, gen)
    if refined is None:
        return x, None
    k = _strata(n, dim)
    near, corners = refined
    sub = _cell_corners(refine, dim)  # (r^d, d)
    u = torch.rand(len(near), len(sub), dim, generator=gen)
    fine = ((corners[:, None] + (sub[None] + u) / refine) / k * 2.0 - 1.0).reshape(-1, dim)
    keep = torch.ones(n, dtype=torch.bool)
    keep[near] = False
    return torch.cat([x[keep], fine]), near


def _tube_part(norm_of_omega, tube: tuple, radius: float, n: int, fraction: float, dim: int, dtype: torch.dtype,
               gen: torch.Generator) -> tuple[float, float, int]:
    """The tube about Γ's share of one chunk: samples of density q ∝ 1/r about Γ, each |ω|/q an unbiased estimate
    of ∫_T∩U |ω| dx, scaled to n cells' worth of E_U|ω|. → (sum, paired square sum, points evaluated)."""
    xt, q = sample_tube(*tube, radius, max(2, int(n * fraction)), gen)
    w = norm_of_omega(xt.to(dtype))
    w = w / q.to(w.device)
    w = w.masked_fill((xt.abs() > 1.0).any(-1).to(w.device), 0.0)
    scale = n / (2.0**dim * len(w))
    return float(w.sum()) * scale, paired_square_sum(w) * scale**2, len(w)


def _cells_part(m: torch.Tensor, n: int, near: torch.Tensor | None) -> tuple[float, float]:
    """One chunk's sum and paired square sum over its n cells, |ω| (or |Bω|) at its points ``m``. A refined cell's
    value is its sub-samples' mean, whose variance its own sub-cells estimate (pairs of neighbouring sub-cells):
    pairing it with a neighbouring cell instead would count the steep change of |ω| towards Γ as variance."""
    if near is None:
        return float(m.sum()), paired_square_sum(m)
    kept = n - len(near)
    sub_values = m[kept:].reshape(len(near), -1)
    return (float(m[:kept].sum() + sub_values.mean(1).sum()),
            paired_square_sum(m[:kept]) + paired_square_sum(sub_values) / sub_values.shape[1] ** 2)


def mass_estimate_settings(evaluation: dict, mesh: trimesh.Trimesh | None = None) -> dict[str, Any]:
    """``mass_estimate``'s num_samples, rel_stderr, refine and tube_radius from a run's ``evaluation`` node (a
    checkpoint written before a key existed gets that key's former behaviour: no stop, no refinement, no tube), and with
    ``evaluation.mass_refine_mesh`` its ``refine_points``: the vertices of ``mesh``, the current's own."""
    rel = evaluation.get("mass_rel_stderr")
    points = None
    if evaluation.get("mass_refine_mesh") and mesh is not None and len(mesh.vertices):
        points = torch.as_tensor(np.asarray(mesh.vertices))
    return {"num_samples": int(evaluation.get("mass_samples", 1 << 20)), "rel_stderr": float(rel) if rel else None,
            "refine": int(evaluation.get("mass_refine", 1)), "refine_points": points,
            "tube_radius": float(evaluation.get("mass_tube_radius") or 0.0)}


def mesh_border_segments(mesh: trimesh.Trimesh) -> tuple[np.ndarray, np.ndarray]:
    """The mesh's border edges as segments (starts (E, 3), ends (E, 3)), whether or not they close loops."""
    edges = border_edges(np.asarray(mesh.faces))
    v = np.asarray(mesh.vertices)
    return v[edges[:, 0]], v[edges[:, 1]]


def boundary_error(mesh: trimesh.Trimesh, loops: list[np.ndarray], spacing: float = 1e-3) -> float | None:
    """Symmetric Hausdorff distance between the mesh's border and Γ (None if the mesh has no border)."""
    a0, a1 = mesh_border_segments(mesh)
    if len(a0) == 0:
        return None
    b0, b1, _ = closed_loop_segments(loops)
    return polyline_hausdorff(a0, a1, b0, b1, spacing)


def mesh_summary(result: Any, loops: list[np.ndarray]) -> dict[str, Any]:
    """What every report says of an extracted surface: ``mesh_area``, ``mesh_faces``, ``boundary_error``
    (None for an empty mesh) and, for a ``MeshingResult``, ``mesh_level``, ``boundary_loops_closed`` and
    ``mesh_closed_area_dropped`` (closed bubbles left out of the mesh, ``eval.meshing.surface``).
    ``result``: a MeshingResult or a trimesh.Trimesh; ``loops``: Γ as (M_i, 3) arrays."""
    mesh = getattr(result, "mesh", result)
    summary: dict[str, Any] = {
        "mesh_area": float(mesh.area),
        "mesh_faces": int(len(mesh.faces)),
        "boundary_error": boundary_error(mesh, loops) if len(mesh.faces) else None,
    }
    if hasattr(result, "mesh"):
        summary["mesh_level"] = result.level
        summary["boundary_loops_closed"] = result.zipped_loops
        summary["mesh_closed_area_dropped"] = float(getattr(result, "closed_area_dropped", 0.0))
    return summary


def curve_length(curves: list[np.ndarray]) -> float:
    """Total length of polylines."""
    return float(sum(np.linalg.norm(np.diff(c, axis=0), axis=1).sum() for c in curves))


def curve_boundary_error(curves: list[np.ndarray], points: np.ndarray) -> float | None:
    """2D: the symmetric Hausdorff distance between the curves' ends and Γ's points (the boundary of a curve is
    its ends, Γ a 0-chain): a point no curve reaches and a curve that stops short of Γ both count.
    curves: polylines (K_i, 2); points (P, 2). None if there is no curve."""
    if not curves:
        return None
    ends = np.concatenate([np.stack([c[0], c[-1]]) for c in curves])
    dist = np.linalg.norm(ends[:, None] - np.asarray(points)[None], axis=-1)  # (2 × curves, P)
    return float(max(dist.min(0).max(), dist.min(1).max()))


def sample_surface_faces(mesh: trimesh.Trimesh, n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``n`` points drawn uniformly (by area) on a triangle mesh, reproducibly, and the face each lies on.
    → (points (n, 3) float64, faces (n,) int)."""
    if len(mesh.faces) == 0:
        raise ValueError("cannot sample an empty mesh")
    points, faces = trimesh.sample.sample_surface(mesh, int(n), seed=seed)
    return np.asarray(points, dtype=np.float64), np.asarray(faces)


def sample_surface(mesh: trimesh.Trimesh, n: int, seed: int = 0) -> np.ndarray:
    """``n`` points drawn uniformly (by area) on a triangle mesh, reproducibly. → (n, 3) float64."""
    return sample_surface_faces(mesh, n, seed)[0]


def sheet_flux(current, mesh: trimesh.Trimesh, num_lines: int = 400, half_width: float = 0.04,
               num_steps: int = 81, seed: int = 0) -> np.ndarray:
    """How much of the jump a current carries across its own mesh: |∫ ω·n ds| along the normal line of
    ``num_lines`` area-uniform points of the mesh, from −half_width to +half_width (trapezoid rule, ``num_steps``
    points), in units of the full jump J = jump(3)·alpha_scale. 1 for a current that steps by J across the mesh;
    below 1 where part of its flux crosses elsewhere (a weaker sheet, whose mass can then be *less* than the mesh's
    area, so that crispness alone would call it clean); above 1 where ω along n wobbles about the mesh within the
    window. Where a part is thinner than 2·half_width the line reaches its far side, whose opposite flux cancels:
    compare values on the same shapes. → (num_lines,) float64."""
    points, faces = sample_surface_faces(mesh, num_lines, seed)
    normals = np.asarray(mesh.face_normals)[faces]
    s = np.linspace(-half_width, half_width, int(num_steps))
    lines = np.asarray(points)[:, None, :] + s[None, :, None] * normals[:, None, :]  # (L, K, 3)
    x = torch.as_tensor(lines.reshape(-1, 3), dtype=torch.float32, device=device_of(current))
    omega = torch.cat([current(c, create_graph=False)[1].detach() for c in torch.split(x, 1 << 15)])
    along = np.einsum("lkd,ld->lk", omega.double().cpu().numpy().reshape(len(points), len(s), 3), normals)
    return np.abs(np.trapezoid(along, s, axis=1)) / (jump(3) * current.alpha_scale)


def point_mesh_distance(points: np.ndarray, mesh: trimesh.Trimesh) -> np.ndarray:
    """Euclidean distance from each point to the closest point of a triangle mesh (libigl, exact).

    points (N, 3) → (N,). An empty mesh is infinitely far.
    """
    points = np.ascontiguousarray(points, dtype=np.float64)
    if len(mesh.faces) == 0:
        return np.full(len(points), np.inf)
    sq, _, _ = igl.point_mesh_squared_distance(
        points, np.ascontiguousarray(mesh.vertices, dtype=np.float64),
        np.ascontiguousarray(mesh.faces, dtype=np.int64),
    )
    return np.sqrt(sq)


def unidirectional_chamfer(target_mesh: trimesh.Trimesh, mesh: trimesh.Trimesh, n: int = 100_000,
                           seed: int = 0) -> float:
    """UCD (paper Tab. 1): E_{y ~ U(target)} dist(y, mesh), by ``n`` uniform samples of the target.

    In the units of the meshes (the paper scales them into [-0.5, 0.5]^3). ``inf`` if ``mesh`` is empty.
    """
    return float(point_mesh_distance(sample_surface(target_mesh, n, seed), mesh).mean())
