"""Random augmentation of a mesh with boundary for family training (paper §5.3).

Per mesh and step:

1. each boundary loop is scaled about its centroid along its two principal directions (the two largest
   axes of its vertices' covariance) by factors from U[0.85, 1.15];
2. those loop displacements are carried to the whole mesh by harmonic skinning weights
   (``geometry.harmonic``: every boundary vertex is a handle);
3. the mesh is rotated about its bounding-box centre by Euler angles (x, y, z) each from U[−10°, 10°];
4. it is shifted by t ~ U[−0.05, 0.05]³, restricted per axis to the shifts that keep every vertex
   inside [−bound, bound]³ (uniform over what remains).

Beyond the paper, off by default (``mesh_scale`` = (1, 1)): before the rotation the whole mesh may be scaled
about the origin by s, log s ~ U[log low, log high] (so that ×0.5 and ×2 are equally likely). The
parts of ``make data`` are each centred at the origin with one scale per category, so a smaller body's part is
close to a scaled copy of a larger one about the origin (hand 000's wrist × 2.1 lies within 0.03 of hand 002's),
and a code then also sees the wrists of its neighbours' sizes and places; the paper's loop scaling (about each
loop's centroid, ×0.85–1.15) cannot reach a wrist twice as wide and 0.20 away.

Steps 1–2 and 3 commute in distribution (the cotangent Laplacian and the principal directions rotate
with the mesh), so this is the paper's order "rotate, rescale loops, propagate, shift". The authors scaled
loops about the origin and added a per-loop offset; scaling about the loop's centroid keeps the loop in
place, so the change is a change of shape only.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from deepcurrents.errors import ConfigError, number_at_least, share
from deepcurrents.geometry.harmonic import HarmonicSkinning

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class AugmentationRanges:
    """The ranges of the random transformations (paper values by default).

    rotation_deg: each Euler angle from U[−rotation_deg, rotation_deg] degrees.
    scale: each loop's two principal scales from U[scale[0], scale[1]].
    shift: each coordinate of the translation from U[−shift, shift].
    bound: the augmented mesh stays inside [−bound, bound]³ (the domain is [−1, 1]³).
    mesh_scale: the whole mesh scaled about the origin by a log-uniform factor in [low, high] (beyond the
        paper; (1, 1), the default, draws nothing, so the paper's random streams are unchanged).
    """

    rotation_deg: float = 10.0
    scale: tuple[float, float] = (0.85, 1.15)
    shift: float = 0.05
    bound: float = 0.98
    mesh_scale: tuple[float, float] = (1.0, 1.0)

    def __post_init__(self):
        if number_at_least("data.rotation_deg", self.rotation_deg) > 180:
            raise ConfigError(f"data.rotation_deg={self.rotation_deg} must be between 0 and 180 degrees.")
        lo, hi = self.scale
        if not 0 < lo <= hi:
            raise ConfigError(f"data.scale_range={list(self.scale)} must be [low, high] with 0 < low ≤ high.")
        number_at_least("data.shift", self.shift)
        share("data.bound", self.bound, "the domain is [-1, 1]^3")
        lo, hi = self.mesh_scale
        if not 0 < lo <= hi:
            raise ConfigError(f"data.mesh_scale_range={list(self.mesh_scale)} must be [low, high] with "
                              "0 < low ≤ high.")


@dataclass
class Augmentation:
    """What one augmentation drew: rotation (3, 3), angles (3,) in radians, per-loop scales (B, 2),
    shift (3,), rotation centre (3,), the whole mesh's scale about the origin (1 when not drawn)."""

    rotation: np.ndarray
    angles: np.ndarray
    scales: np.ndarray
    shift: np.ndarray
    centre: np.ndarray
    mesh_scale: float = 1.0


def euler_rotation(angles: np.ndarray) -> np.ndarray:
    """R = R_z(γ) R_y(β) R_x(α) for angles (α, β, γ) in radians. → (3, 3)."""
    a, b, g = angles
    rx = np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])
    ry = np.array([[math.cos(b), 0, math.sin(b)], [0, 1, 0], [-math.sin(b), 0, math.cos(b)]])
    rz = np.array([[math.cos(g), -math.sin(g), 0], [math.sin(g), math.cos(g), 0], [0, 0, 1]])
    return rz @ ry @ rx


def principal_directions(points: np.ndarray) -> np.ndarray:
    """Orthonormal principal axes of a point set, largest variance first, as columns. (M, 3) → (3, 3)."""
    centred = points - points.mean(0)
    evals, evecs = np.linalg.eigh(centred.T @ centred)
    return evecs[:, np.argsort(evals)[::-1]]


def scale_loop(loop: np.ndarray, s1: float, s2: float) -> np.ndarray:
    """The loop scaled about its centroid by s1, s2 along its first two principal directions. (M, 3) → (M, 3)."""
    c = loop.mean(0)
    p = principal_directions(loop)
    stretch = p @ np.diag([s1, s2, 1.0]) @ p.T
    return c + (loop - c) @ stretch.T


def _uniform(generator: torch.Generator, size, lo, hi) -> np.ndarray:
    u = torch.rand(size, generator=generator, dtype=torch.float64).numpy()
    return lo + u * (np.asarray(hi) - np.asarray(lo))


def feasible_shift(vertices: np.ndarray, bound: float) -> tuple[np.ndarray, np.ndarray]:
    """Per axis, the interval [lo, hi] of translations that keep every vertex in [−bound, bound]. → (3,), (3,)."""
    return -bound - vertices.min(0), bound - vertices.max(0)


def augment_mesh(
    skinning: HarmonicSkinning,
    loops: Sequence[np.ndarray],
    generator: torch.Generator,
    ranges: AugmentationRanges = AugmentationRanges(),
) -> tuple[np.ndarray, Augmentation]:
    """One random augmentation of a mesh (see the module docstring).

    Args:
        skinning: the mesh's HarmonicSkinning, whose handles are the loops' vertices concatenated in order.
        loops: B index arrays (M_b,) into the mesh's vertices, one per boundary loop.
        generator: the torch random stream (per rank, worker and resume step).
    Returns:
        the augmented vertices (V, 3) float64 (faces are unchanged) and what was drawn.
    """
    vertices = skinning.vertices
    lo, hi = ranges.scale
    scales = _uniform(generator, (len(loops), 2), lo, hi)
    targets = np.concatenate([scale_loop(vertices[idx], s1, s2)
                              for idx, (s1, s2) in zip(loops, scales, strict=True)])
    v = skinning.deform(targets)

    mesh_scale = 1.0
    if ranges.mesh_scale != (1.0, 1.0):  # drawn only when asked for: the paper's streams stay as they were
        log_lo, log_hi = np.log(ranges.mesh_scale)
        mesh_scale = float(np.exp(_uniform(generator, 1, log_lo, log_hi)[0]))
        v = v * mesh_scale

    angles = np.deg2rad(_uniform(generator, 3, -ranges.rotation_deg, ranges.rotation_deg))
    rot = euler_rotation(angles)
    centre = mesh_scale * 0.5 * (vertices.min(0) + vertices.max(0))  # the (scaled) box centre
    v = centre + (v - centre) @ rot.T

    t = _uniform(generator, 3, -ranges.shift, ranges.shift)
    flo, fhi = feasible_shift(v, ranges.bound)
    if np.any(flo > fhi):  # wider than the box on some axis: shrink about its centre so that it fits
        mid = 0.5 * (v.min(0) + v.max(0))
        factor = ranges.bound / float(np.max(0.5 * (v.max(0) - v.min(0))))
        log.debug("augmented mesh wider than the domain; shrunk by %.4f", factor)
        v = mid + (v - mid) * factor
        flo, fhi = feasible_shift(v, ranges.bound)
    # uniform over the allowed part of [−shift, shift]; if none of it is allowed, the smallest allowed move
    a, b = np.maximum(flo, -ranges.shift), np.minimum(fhi, ranges.shift)
    inside = a <= b
    frac = (t + ranges.shift) / (2 * ranges.shift) if ranges.shift > 0 else np.full(3, 0.5)
    t = np.where(inside, a + frac * (b - a), np.clip(0.0, flo, fhi))
    return v + t, Augmentation(rot, angles, scales, t, centre, mesh_scale)
