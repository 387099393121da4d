"""Correspondence of boundary loops across shapes: which loop is which, where each loop starts, and
vertex-wise interpolation between corresponding loops (families of surfaces, paper §5.3).

How loops are matched (used by the family dataset and by boundary editing):

1. *Which loop*: the loops of a shape are assigned to the reference shape's loops by the Hungarian
   method on the distances between loop centroids (shapes of a category are rigidly aligned).
2. *Orientation*: a loop's orientation comes from its mesh's faces and is not changed; a loop whose vector
   area points against its reference's is reported (``orientation_agrees``).
3. *Start vertex*: the vertex order is cyclically shifted so that the loop starts where the reference
   starts: with equal vertex counts, the shift minimising Σ_i |v_{i+s} − r_i|² (centroids removed);
   otherwise the vertex nearest to the reference's first vertex (centroids removed). The boundary encoder
   is invariant to this shift; boundary interpolation needs it.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import numpy as np
from scipy.optimize import linear_sum_assignment

from deepcurrents.geometry.curves import BoundaryError

log = logging.getLogger("deepcurrents")


def loop_vector_area(loop: np.ndarray) -> np.ndarray:
    """½ Σ_i v_i × v_{i+1} of a closed loop (its orientation times its spanned area). (M, 3) → (3,)."""
    c = loop - loop.mean(0)
    return 0.5 * np.cross(c, np.roll(c, -1, 0)).sum(0)


def match_loops(loops: Sequence[np.ndarray], reference: Sequence[np.ndarray]) -> np.ndarray:
    """Permutation p with loops[p[j]] ↔ reference[j], minimising the total centroid distance. → (B,)."""
    a = np.stack([np.asarray(lp).mean(0) for lp in loops])
    b = np.stack([np.asarray(lp).mean(0) for lp in reference])
    cost = np.linalg.norm(b[:, None] - a[None], axis=-1)  # (B_ref, B)
    rows, cols = linear_sum_assignment(cost)
    perm = np.empty(len(reference), dtype=np.int64)
    perm[rows] = cols
    return perm


def best_cyclic_shift(loop: np.ndarray, reference: np.ndarray) -> int:
    """The shift s such that ``np.roll(loop, -s, 0)`` starts where ``reference`` starts (see module doc)."""
    a = loop - loop.mean(0)
    r = reference - reference.mean(0)
    if len(a) == len(r):
        # all shifts at once: cost[s] = Σ_i |a_{(i+s) mod n} − r_i|²
        n = len(a)
        idx = (np.arange(n)[:, None] + np.arange(n)[None, :]) % n  # [s, i] → i + s
        cost = ((a[idx] - r[None]) ** 2).sum((1, 2))
        return int(cost.argmin())
    return int(np.linalg.norm(a - r[0], axis=1).argmin())


def orientation_agrees(loop: np.ndarray, reference: np.ndarray) -> bool:
    """True when the two loops turn the same way (their vector areas have a non-negative dot product)."""
    return float(loop_vector_area(loop) @ loop_vector_area(reference)) >= 0.0


def align_loops(loops: Sequence[np.ndarray], reference: Sequence[np.ndarray], source: str) -> list[np.ndarray]:
    """New loops ordered like ``reference`` (a training shape's loops, by centroids) and each oriented like its match
    (reversed, with a warning, where it turns the other way), so that a family's current points the way its surfaces
    do. ``source`` names the loops in messages. BoundaryError (one sentence) when the loop counts differ."""
    if len(loops) != len(reference):
        raise BoundaryError(
            f"{source} has {len(loops)} loop{'s' if len(loops) != 1 else ''} but this family's shapes have "
            f"{len(reference)}; give one closed loop per boundary of the family."
        )
    out = []
    for b, j in enumerate(match_loops(loops, reference)):
        lp = np.asarray(loops[j])
        if not orientation_agrees(lp, reference[b]):
            log.warning("%s: loop %d turns against the family's loop %d; reversed it.", source, b, b)
            lp = lp[::-1].copy()
        out.append(lp)
    return out


def resample_loop(loop: np.ndarray, n: int) -> np.ndarray:
    """``n`` points equally spaced by arc length along a closed loop, the first at its first vertex. → (n, 3)."""
    ends = np.roll(loop, -1, 0)
    seglen = np.linalg.norm(ends - loop, axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seglen)])  # (M + 1,)
    s = np.arange(n) * cum[-1] / n
    seg = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(loop) - 1)
    t = (s - cum[seg]) / np.maximum(seglen[seg], 1e-30)
    return loop[seg] + t[:, None] * (ends[seg] - loop[seg])


def interpolate_loops(loops_a: Sequence[np.ndarray], loops_b: Sequence[np.ndarray], t: float) -> list[np.ndarray]:
    """Vertex-wise (1 − t)·a + t·b of corresponding loops (same order, aligned starts).

    Loops with different vertex counts are first resampled by arc length to the larger count.
    """
    out = []
    for a, b in zip(loops_a, loops_b, strict=True):
        a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
        if len(a) != len(b):
            n = max(len(a), len(b))
            a, b = resample_loop(a, n), resample_loop(b, n)
        out.append((1.0 - t) * a + t * b)
    return out
