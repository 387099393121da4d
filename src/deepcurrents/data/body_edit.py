"""Boundaries as handles: moving one shared loop of a body folder (``data.body_partition``) and deforming the parts
around it, so that refitting them from their checkpoints gives the edited body (``experiments.stitched``).

A move is a similarity about the loop's centroid c: x ↦ c + s R (x − c) + t (a rotation by ``rotate`` degrees about
``axis``, default the loop's longest in-plane direction, the hinge of an elbow or a knee; a scale s; a translation t).

- ``carry=True`` (bending a limb): the loop's child part and every part below it move with the loop, rigidly (a
  similarity maps their fitted currents exactly, so they need no refit), and the parent part is deformed to meet the
  moved loop, its other loops fixed;
- ``carry=False`` (reshaping a joint): only the loop moves; both parts it joins are deformed, their other loops fixed.

The deformed parts follow a biharmonic interpolation of the displacements (libigl's k = 2 harmonic coordinates on the
body mesh) within ``reach`` × the loop's diameter of the loop: smooth there, the loops exactly where they were moved
to, the rest of each part where it was (a part with one loop, a hand or the head, would otherwise swing whole).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import igl
import numpy as np
from scipy.spatial.transform import Rotation

from deepcurrents.data.body_partition import StitchedBody
from deepcurrents.data.human_parts import DatasetError
from deepcurrents.geometry.polyline import closest_on_segments


@dataclass(frozen=True)
class LoopMove:
    """A similarity about a loop's centroid: ``rotate`` degrees about ``axis`` (None: the loop's longest in-plane
    direction), then ``scale``, then ``translate``."""

    rotate: float = 0.0
    axis: Sequence[float] | None = None
    scale: float = 1.0
    translate: Sequence[float] = (0.0, 0.0, 0.0)

    def hinge(self, loop: np.ndarray) -> np.ndarray:
        """The rotation's unit axis for this loop (M, 3)."""
        if self.axis is not None:
            axis = np.asarray(self.axis, np.float64)
            if axis.shape != (3,) or not np.isfinite(axis).all() or np.linalg.norm(axis) == 0:
                raise DatasetError(f"The rotation axis {list(self.axis)} must be three numbers, not all zero.")
            return axis / np.linalg.norm(axis)
        _, _, vt = np.linalg.svd(loop - loop.mean(0))
        return vt[0]

    def apply(self, points: np.ndarray, loop: np.ndarray) -> np.ndarray:
        """The moved points (N, 3), the move made about ``loop``'s centroid."""
        if not (np.isfinite(self.scale) and self.scale > 0):
            raise DatasetError(f"The scale {self.scale} must be a positive number.")
        centre = loop.mean(0)
        rotation = Rotation.from_rotvec(np.deg2rad(self.rotate) * self.hinge(loop)).as_matrix()
        return centre + self.scale * (points - centre) @ rotation.T + np.asarray(self.translate, np.float64)


def parts_below(body: StitchedBody, name: str) -> list[str]:
    """``name`` and every part that hangs from it, directly or not."""
    below, frontier = [name], [name]
    while frontier:
        children = [p for p, info in body.parts.items() if info.get("parent") in frontier]
        below += children
        frontier = children
    return below


def move_loop(body: StitchedBody, loop_name: str, move: LoopMove, carry: bool = True, reach: float = 0.75
              ) -> tuple[np.ndarray, list[str], list[str]]:
    """The body's vertices after the move (module docstring). → (vertices (V, 3), the parts deformed (to refit),
    the parts moved rigidly)."""
    if not (np.isfinite(reach) and reach > 0):
        raise DatasetError(f"reach={reach} must be a positive multiple of the loop's diameter.")
    loops = {name: (pair, idx) for name, pair, _, idx in body.loops}
    if loop_name not in loops:
        raise DatasetError(f"The body '{body.folder}' has no loop {loop_name!r}; its loops are "
                           f"{', '.join(sorted(loops))}.")
    (child, parent), idx = loops[loop_name]
    verts = body.body_vertices
    loop = verts[idx]
    moved = np.zeros(len(verts), bool)
    rigid = parts_below(body, child) if carry else []
    for name in rigid:
        moved[np.asarray(body.parts[name]["body_vertices"], np.int64)] = True
    moved[idx] = True
    refit = [parent] if carry else [child, parent]
    free = np.zeros(len(verts), bool)
    for name in refit:
        free[np.asarray(body.parts[name]["body_vertices"], np.int64)] = True
    for _, _, _, other in body.loops:  # every loop is held: moved with the rest, or where it is
        free[other] = False
    diameter = float(np.linalg.norm(loop[:, None] - loop[None], axis=-1).max())
    near, _, _ = closest_on_segments(verts, loop, np.roll(loop, -1, 0))
    free &= near < reach * diameter
    free &= ~moved
    target = verts.copy()
    target[moved] = move.apply(verts[moved], loop)
    fixed = np.flatnonzero(~free)
    displacement = igl.harmonic(np.ascontiguousarray(verts), np.ascontiguousarray(body.body_faces, np.int64),
                                fixed.astype(np.int64), np.ascontiguousarray(target[fixed] - verts[fixed]), 2)
    out = verts + displacement
    out[fixed] = target[fixed]
    return out, refit, rigid
