"""Boundary curves Γ: the paper's knots and links, circles, curve files, and their validation.

A 3D boundary is a list of closed polygonal loops, each an (M, 3) tensor whose vertex order is the
orientation; the last vertex connects to the first. A 2D boundary is a set of signed points.
"""

from __future__ import annotations

import logging
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from deepcurrents.errors import UserInputError
from deepcurrents.geometry.polyline import resample_loop
from deepcurrents.geometry.topology import edge_walks, first_copies

log = logging.getLogger(__name__)


class BoundaryError(UserInputError):
    """A boundary (curve file, named curve or point set) that cannot be used; the message says why."""


def _param(n: int) -> np.ndarray:
    return 2.0 * np.pi * np.arange(n) / n


def circle(
    radius: float = 0.6,
    center: tuple[float, float, float] = (0.0, 0.0, 0.0),
    normal: tuple[float, float, float] = (0.0, 0.0, 1.0),
    n: int = 100,
) -> np.ndarray:
    """A circle of ``n`` vertices, counter-clockwise seen from the tip of ``normal``. → (n, 3)."""
    nrm = np.asarray(normal, dtype=np.float64)
    nrm = nrm / np.linalg.norm(nrm)
    helper = np.array([1.0, 0.0, 0.0]) if abs(nrm[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(nrm, np.cross(helper, nrm))
    u /= np.linalg.norm(u)
    v = np.cross(nrm, u)
    t = _param(n)
    return np.asarray(center) + radius * (np.cos(t)[:, None] * u + np.sin(t)[:, None] * v)


def trefoil(n: int = 100) -> list[np.ndarray]:
    """The authors' trefoil: (1/6)(sin t + 2 sin 2t, cos t − 2 cos 2t, −sin 3t)."""
    t = _param(n)
    pts = np.stack([np.sin(t) + 2 * np.sin(2 * t), np.cos(t) - 2 * np.cos(2 * t), -np.sin(3 * t)], 1) / 6.0
    return [pts]


def hopf_link(n: int = 100) -> list[np.ndarray]:
    """Circles of radius 0.6 centred at (∓0.3, 0, 0), one in the xy-plane, one in the xz-plane."""
    t = _param(n)
    c, s, z = 0.6 * np.cos(t), 0.6 * np.sin(t), np.zeros(n)
    return [np.stack([c - 0.3, s, z], 1), np.stack([c + 0.3, z, s], 1)]


def borromean_rings(n: int = 100) -> list[np.ndarray]:
    """Three ellipses, semi-axes 0.6 and 0.3, in the three coordinate planes, cyclically permuted."""
    t = _param(n)
    a, b, z = 0.6 * np.cos(t), 0.3 * np.sin(t), np.zeros(n)
    return [np.stack([a, b, z], 1), np.stack([z, a, b], 1), np.stack([b, z, a], 1)]


def enneper(n: int = 100, radius: float = 0.8) -> list[np.ndarray]:
    """The border of Enneper's surface over the parameter disc of ``radius`` (< 1):
    (u − u³/3 + uv², −v + v³/3 − u²v, u² − v²) at (u, v) = radius·(cos t, sin t). For radius < 1 the
    surface is the curve's unique minimal surface, of area :func:`enneper_area` (a known exact area that is
    not planar; radius 0.8 reaches 0.97 from the origin, 0.70 in each coordinate)."""
    t = _param(n)
    u, v = radius * np.cos(t), radius * np.sin(t)
    return [np.stack([u - u**3 / 3 + u * v**2, -v + v**3 / 3 - u**2 * v, u**2 - v**2], 1)]


def enneper_area(radius: float = 0.8) -> float:
    """Exact area of Enneper's surface over the parameter disc of ``radius``: π(r² + r⁴ + r⁶/3)
    (its metric is (1 + u² + v²)² (du² + dv²))."""
    return float(np.pi * (radius**2 + radius**4 + radius**6 / 3))


NAMED_CURVES = {
    "trefoil": trefoil,
    "hopf": hopf_link,
    "hopf_link": hopf_link,
    "borromean": borromean_rings,
    "borromean_rings": borromean_rings,
    "circle": lambda n=100: [circle(0.6, n=n)],
    "enneper": enneper,
}


def read_curve_file(path: str | Path) -> list[np.ndarray]:
    """Loops from a file: ``.obj`` polylines (one ``l`` element per loop, ``v`` vertices), ``.txt`` / ``.csv`` with
    one ``x y z`` row per vertex (blank lines between loops), or ``.npy`` with one loop. A repeated first vertex at
    the end of a loop is dropped. Raises BoundaryError with one sentence for unreadable or malformed files."""
    path = Path(path)
    if not path.exists():
        raise BoundaryError(f"Curve file '{path}' does not exist.")
    if path.is_dir():
        raise BoundaryError(f"Curve file '{path}' is a directory, not a file.")
    suffix = path.suffix.lower()
    try:
        if suffix == ".obj":
            loops = _read_obj_polylines(path)
        elif suffix == ".npy":
            loops = [np.load(path, allow_pickle=False).astype(np.float64)]
        elif suffix in (".txt", ".xyz", ".csv"):
            loops = _read_text_loops(path)
        else:
            raise BoundaryError(
                f"Curve file '{path}' has unsupported extension '{suffix}' (use .obj, .txt or .npy)."
            )
    except BoundaryError:
        raise
    except (OSError, ValueError, UnicodeDecodeError) as err:
        raise BoundaryError(f"Curve file '{path}' could not be read: {err}.") from err
    if not loops or all(len(loop) == 0 for loop in loops):
        raise BoundaryError(f"Curve file '{path}' contains no curve vertices.")
    for i, loop in enumerate(loops):
        if loop.ndim != 2 or loop.shape[1] != 3:
            raise BoundaryError(
                f"Curve file '{path}': loop {i} must have 3 coordinates per vertex, got shape {loop.shape}."
            )
    if suffix != ".obj":  # .obj files say so for their 'l' elements (_read_obj_polylines)
        _warn_open_loops(loops, path)
    # a loop written closed (last vertex = first) is the same loop
    return [lp[:-1] if len(lp) > 1 and np.array_equal(lp[0], lp[-1]) else lp for lp in loops]


def _warn_open_loops(loops: list[np.ndarray], path: Path) -> None:
    """A warning for each loop (M, 3) whose closing step (last vertex to first) is over twice its longest other step:
    a curve written open (an arc, a polyline), which is closed by that straight step, as every boundary loop is."""
    for i, loop in enumerate(loops):
        if loop.ndim != 2 or len(loop) < 3:
            continue  # refused later (validate_loops), in one sentence
        longest = float(np.linalg.norm(np.diff(loop, axis=0), axis=1).max())
        gap = float(np.linalg.norm(loop[-1] - loop[0]))
        if gap > 2 * longest:
            log.warning("Curve file '%s': loop %d does not come back to its start (its last vertex is %.3g from its "
                        "first, %.1f× its longest step); it is closed by that straight step, as every boundary "
                        "loop is.", path, i, gap, gap / longest)


def _read_text_loops(path: Path) -> list[np.ndarray]:
    """Rows of numbers (spaces or commas), one vertex per row; ``#`` starts a comment; a first row of words only
    (a CSV header such as ``x,y,z``) is skipped; blank lines separate loops when every block they delimit is a
    closed loop of its own (``_closes``); otherwise they are spacing (double line ends, double spacing, a stray
    blank line inside a loop)."""
    blocks: list[list[list[float]]] = [[]]
    seen_row = False
    for number, raw in enumerate(path.read_text(encoding="utf-8-sig").splitlines(), start=1):
        tokens = raw.split("#", 1)[0].replace(",", " ").split()
        if not tokens:
            if not raw.strip() and blocks[-1]:
                blocks.append([])
            continue
        try:
            blocks[-1].append([float(t) for t in tokens])
        except ValueError:
            if not seen_row and not any(_is_number(t) for t in tokens) and any(c.isalpha() for c in raw):
                seen_row = True
                continue  # a header row (words: x,y,z), not numbers joined by another separator
            hint = " ';' is not a separator: use spaces or commas" if ";" in raw else " comment it out with '#'"
            raise BoundaryError(f"Curve file '{path}': line {number} ({raw.strip()[:40]!r}) is not a row of "
                                f"numbers ({hint.strip()}).") from None
        seen_row = True
    blocks = [rows for rows in blocks if rows]
    open_blocks = [i for i, rows in enumerate(blocks) if not _closes(np.array(rows, dtype=np.float64))]
    if len(blocks) > 1 and open_blocks:  # spacing inside one loop, not loops
        if sum(len(rows) >= 3 for rows in blocks) >= 2:  # blocks that could be loops: said (not double spacing)
            log.warning("Curve file '%s': its %d blank-line-separated blocks are read as ONE loop, because block %d "
                        "does not close on itself (its last-to-first step is over twice its median step); if they are "
                        "separate loops (a D shape closed by its chord), write them as .obj 'l' elements.", path,
                        len(blocks), open_blocks[0] + 1)
        blocks = [[row for rows in blocks for row in rows]]
    if len(blocks) > 1:
        log.info("Curve file '%s': %d loops (blank lines separate them).", path, len(blocks))
    return [np.array(rows, dtype=np.float64) for rows in blocks]


def _closes(rows: np.ndarray) -> bool:
    """Whether a block of rows (M, d) reads as a closed loop: at least 3 vertices, and its closing step (last to
    first) no longer than twice its median step."""
    if len(rows) < 3 or rows.ndim != 2:
        return False
    steps = np.linalg.norm(np.diff(rows, axis=0), axis=1)
    return bool(np.linalg.norm(rows[-1] - rows[0]) <= 2 * np.median(steps))


def _is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def write_curve_file(path: str | Path, loops: list[np.ndarray]) -> None:
    """Writes closed loops as an ``.obj`` polyline file that ``read_curve_file`` reads back exactly: ``v``
    lines, then one ``l`` element per loop (closed implicitly: the last vertex connects to the first)."""
    lines, base = [], 1
    for loop in loops:
        lines += [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in np.asarray(loop, dtype=np.float64)]
    for loop in loops:
        idx = range(base, base + len(loop))
        lines.append("l " + " ".join(map(str, idx)))
        base += len(loop)
    Path(path).write_text("\n".join(lines) + "\n")


def _read_obj_polylines(path: Path) -> list[np.ndarray]:
    verts: list[list[float]] = []
    lines: list[list[int]] = []
    has_faces = False
    for raw in path.read_text().splitlines():
        parts = raw.split("#", 1)[0].split()
        if not parts:
            continue
        if parts[0] == "v":
            verts.append([float(x) for x in parts[1:4]])
        elif parts[0] == "l":
            lines.append([int(tok.split("/")[0]) for tok in parts[1:]])
        elif parts[0] == "f":
            has_faces = True
    if not verts:
        return []
    v = np.asarray(verts, dtype=np.float64)
    if not lines:
        if has_faces:  # a surface, not a curve: its vertices in file order would be a meaningless loop
            raise BoundaryError(f"Curve file '{path}' holds a mesh (f elements) but no 'l' polylines; give the "
                                "boundary curve as 'l' elements (a mesh to reconstruct goes to experiment=recon_mesh "
                                "data.mesh=…).")
        _warn_open_loops([v], path)
        return [v]  # vertices only: one loop in file order
    # a vertex written once per segment is one vertex (copies within a millionth of the curve's size: printed
    # with fewer digits, they need not be equal)
    same = first_copies(v, 1e-6 * max(float(np.ptp(v, axis=0).max()), 1e-300))
    for k, idx in enumerate(lines):
        idx = [i - 1 if i > 0 else len(v) + i for i in idx]
        if not idx or min(idx) < 0 or max(idx) >= len(v):
            raise BoundaryError(f"Curve file '{path}' has an 'l' element referring to a missing vertex.")
        lines[k] = [int(same[i]) for i in idx]
    # elements of three or more vertices come first in the loops returned; chains of segments say so themselves
    _warn_open_loops([v[idx] for idx in lines if len(idx) != 2], path)
    return [v[idx] for idx in _join_segments(lines, path)]


def _join_segments(lines: list[list[int]], path: Path) -> list[list[int]]:
    """The loops of ``l`` elements as vertex index lists: an element of three or more vertices is a loop (closed
    implicitly); 2-vertex elements, as exporters write a curve edge by edge and in either direction, are walked
    through their shared vertices into simple loops (``topology.edge_walks``: loops that touch at a vertex stay
    apart), each run the way most of its segments are written. One sentence where an odd number (≥ 3) of segments
    meet at a vertex (a branch); a chain with two open ends is closed, with a warning."""
    loops = [idx for idx in lines if len(idx) != 2]
    segments = [(idx[0], idx[1]) for idx in lines if len(idx) == 2 and idx[0] != idx[1]]
    if not segments:
        return loops
    degree = Counter(u for segment in segments for u in segment)
    branch = next((u for u, n in degree.items() if n % 2 and n > 1), None)
    if branch is not None:
        raise BoundaryError(f"Curve file '{path}' branches: {degree[branch]} 'l' segments meet at vertex "
                            f"{branch + 1}; a boundary is made of closed loops.")
    opened = 0
    for walk, along, closed in edge_walks(segments, directed=False):
        opened += not closed
        loops.append(walk if 2 * sum(along) >= len(along) else [walk[0], *walk[:0:-1]])  # most segments' way
    if opened:
        log.warning("Curve file '%s': %d chain(s) of 'l' segments did not close; each was closed by joining its "
                    "two ends.", path, opened)
    return loops


@dataclass
class Boundary:
    """A validated 3D boundary: closed loops (float64 numpy, each (M_i, 3)) and where they came from.

    ``loops`` are in model coordinates (inside the box U); ``scale`` and ``offset`` map them back to the
    coordinates the curve was given in: input = model · scale + offset (identity unless it was normalised).
    """

    loops: list[np.ndarray]
    name: str
    scale: float = 1.0
    offset: np.ndarray = field(default_factory=lambda: np.zeros(3))

    @property
    def normalized(self) -> bool:
        return self.scale != 1.0 or bool(np.any(np.asarray(self.offset) != 0))

    def to_input(self, points: np.ndarray) -> np.ndarray:
        """Model coordinates → the input's. (N, 3) → (N, 3)."""
        return np.asarray(points, dtype=np.float64) * self.scale + np.asarray(self.offset, dtype=np.float64)

    def tensors(self, dtype: torch.dtype = torch.float32, device: torch.device | str = "cpu") -> list[torch.Tensor]:
        return [torch.as_tensor(loop, dtype=dtype, device=device) for loop in self.loops]

    @property
    def num_vertices(self) -> int:
        return sum(len(loop) for loop in self.loops)

    def length(self) -> float:
        return polyline_length(self.loops)


def validate_loops(loops: list[np.ndarray], source: str, domain: float = 1.0,
                   rescale: str = "let data.normalize=auto or true centre and scale it") -> list[np.ndarray]:
    """Checks and cleans closed loops; raises BoundaryError with one sentence naming ``source``.

    Drops a repeated closing vertex and consecutive duplicate vertices (with a warning); rejects NaN/inf,
    loops with fewer than 3 distinct vertices, collinear (zero-area) loops and vertices outside the
    open domain (−domain, domain)^3.
    """
    clean = []
    for i, loop in enumerate(loops):
        name = f"{source}" + (f" (loop {i})" if len(loops) > 1 else "")
        loop = np.asarray(loop, dtype=np.float64)
        if loop.ndim != 2 or loop.shape[1] != 3:
            raise BoundaryError(f"Boundary {name} must be an (M, 3) array of vertices, got shape {loop.shape}.")
        if not np.isfinite(loop).all():
            raise BoundaryError(f"Boundary {name} has NaN or infinite coordinates.")
        seg = np.linalg.norm(np.roll(loop, -1, 0) - loop, axis=1)
        scale = max(float(np.abs(loop).max()), 1e-12)
        dup = seg <= 1e-9 * scale
        if dup.any():
            log.warning("Boundary %s: dropped %d consecutive duplicate vertices.", name, int(dup.sum()))
            loop = loop[~dup]
        if len(loop) < 3:
            raise BoundaryError(
                f"Boundary {name} has {len(loop)} distinct vertices; a closed loop needs at least 3."
            )
        centred = loop - loop.mean(0)
        sv = np.linalg.svd(centred, compute_uv=False)
        if sv[1] <= 1e-9 * max(sv[0], 1e-300):
            raise BoundaryError(f"Boundary {name} is degenerate: its vertices are collinear.")
        if np.abs(loop).max() >= domain:
            raise BoundaryError(
                f"Boundary {name} has vertices outside the domain [-{domain:g}, {domain:g}]^3 "
                f"(max |coordinate| = {np.abs(loop).max():.3g}); rescale it, or {rescale}."
            )
        clean.append(loop)
    if not clean:
        raise BoundaryError(f"Boundary {source} has no loops.")
    return clean


def warn_retraced(loops: list[np.ndarray], source: str) -> None:
    """Warnings for a curve file that draws a curve twice: a loop passing a third or more of its vertices twice
    (round twice, or out and back), or two loops through the same vertices. α doubles or cancels such a curve,
    which is rarely what was meant; not refused, as a boundary of multiplicity two is still a current's."""
    for i, loop in enumerate(loops):
        repeated = len(loop) - len(np.unique(loop, axis=0))
        if repeated >= max(len(loop) // 3, 1):
            name = f"{source}" + (f" (loop {i})" if len(loops) > 1 else "")
            log.warning("Boundary %s passes %d of its vertices twice (traced twice, or back along itself), so α "
                        "doubles or cancels the curve there.", name, repeated)
    keys = [frozenset(map(tuple, lp)) for lp in loops]
    for j in range(len(loops)):
        for i in range(j):
            if keys[i] == keys[j]:
                log.warning("Boundary %s: loops %d and %d are the same curve; α doubles it (or cancels it, if "
                            "they run opposite ways).", source, i, j)


# Curves are kept this far inside the box U = [-1, 1]^3: f has no condition on ∂U, so a current may end on the
# wall instead of spanning Γ: the spanned area falls short once a curve reaches past 0.6 of the box
# (benchmarks/curve_margin.py; docs/notes/code.md). "auto" normalises a curve reaching beyond SAFE_EXTENT into the
# centred box of half-size NORMALIZED_EXTENT (a further 0.1 of margin for curves that bend towards the wall more).
SAFE_EXTENT = 0.6
NORMALIZED_EXTENT = 0.5
# "auto" also scales up a curve whose bounding box's largest half-size is below SMALL_EXTENT: the network's
# features have a fixed resolution in the box, so the smeared jump of f is wider relative to a small curve
# (docs/notes/code.md). The paper's named curves are above it.
SMALL_EXTENT = 0.45


def box_normalisation(points: np.ndarray, mode: bool | str, half_extent: float, safe_extent: float,
                      what: str = "The input", small_extent: float | None = None) -> tuple[float, np.ndarray]:
    """(scale, offset) with model coordinates = (input − offset) / scale. points: (N, 3).

    mode True: centre the bounding box and fit it in [-half_extent, half_extent]^3; "auto": the same, only
    when some |coordinate| exceeds ``safe_extent`` or (if ``small_extent`` is given) the box's largest half-size
    is below ``small_extent`` (logged, naming ``what``); False: identity (1, 0).
    """
    points = np.asarray(points, dtype=np.float64)
    lo, hi = points.min(0), points.max(0)
    reach = float(np.abs(points).max())
    size = float((hi - lo).max())
    if mode == "auto":
        small = small_extent is not None and 0 < size < 2 * small_extent
        mode = reach > safe_extent or small
        if reach > safe_extent:
            log.info("%s reaches |coordinate| = %.4g (safe: %g); it is centred and scaled into [-%g, %g]^3 "
                     "(data.normalize=auto; outputs are written back in its own coordinates).",
                     what, reach, safe_extent, half_extent, half_extent)
        elif small:
            log.info("%s is small (half-size %.4g, below %g); it is centred and scaled up into [-%g, %g]^3 "
                     "(data.normalize=auto; outputs are written back in its own coordinates).",
                     what, size / 2, small_extent, half_extent, half_extent)
    if not mode:
        return 1.0, np.zeros(3)
    if size <= 0:
        return 1.0, np.zeros(3)  # a single point: the validation that follows names the problem
    return size / (2 * half_extent), 0.5 * (lo + hi)


def load_boundary(spec: str, n: int = 100, scale: float = 1.0, domain: float = 1.0,
                  normalize: bool | str = False, max_vertices: int | None = None,
                  setting: str = "data.curve") -> Boundary:
    """A boundary from a name in NAMED_CURVES (sampled with ``n`` vertices per loop) or a curve file path.

    ``scale`` multiplies the coordinates; the result is "the input" that outputs are reported in.
    ``normalize`` (True, "auto", False): centre and scale the loops into the box, see
    :func:`box_normalisation` (auto: only beyond SAFE_EXTENT or below SMALL_EXTENT); the Boundary keeps the map
    back.
    ``max_vertices``: loops with more vertices are resampled by arc length to that many, corners kept
    (:func:`deepcurrents.geometry.polyline.resample_loop`), with a warning; None keeps every vertex.
    ``setting``: the name the caller's user gave the curve under (``data.curve``, an app's ``curve``)."""
    if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not np.isfinite(scale) or scale <= 0:
        raise BoundaryError(f"The curve scale {scale!r} must be a positive number.")
    key = str(spec).strip()
    if key.lower() in NAMED_CURVES:
        loops = NAMED_CURVES[key.lower()](n)
        name = key.lower()
    else:
        if not any(key.lower().endswith(ext) for ext in (".obj", ".txt", ".npy", ".xyz", ".csv")):
            raise BoundaryError(
                f"{setting}='{key}' is neither a known curve ({', '.join(sorted(NAMED_CURVES))}) nor a "
                "curve file (.obj, .txt, .csv, .npy)."
            )
        loops = read_curve_file(key)
        name = Path(key).stem
    loops = validate_loops([np.asarray(loop, dtype=np.float64) * scale for loop in loops], f"'{key}'",
                           domain=np.inf)
    warn_retraced(loops, f"'{key}'")
    if max_vertices is not None:
        loops = [_resample(lp, int(max_vertices), f"'{key}'" + (f" (loop {i})" if len(loops) > 1 else ""))
                 for i, lp in enumerate(loops)]
    factor, offset = box_normalisation(np.concatenate(loops), normalize, NORMALIZED_EXTENT, SAFE_EXTENT,
                                       f"Curve '{key}'", small_extent=SMALL_EXTENT)
    loops = [(lp - offset) / factor for lp in loops]
    rescale = ("let data.normalize=auto or true centre and scale it" if setting == "data.curve" else
               f"give {setting}_scale=… to scale it")
    return Boundary(validate_loops(loops, f"'{key}'", domain=domain, rescale=rescale), name, factor, offset)


def _resample(loop: np.ndarray, n: int, name: str) -> np.ndarray:
    if len(loop) <= n:
        return loop
    out = resample_loop(loop, n)
    before, after = polyline_length([loop]), polyline_length([out])
    log.warning("Boundary %s has %d vertices; resampled by arc length to %d, corners kept (length %.6g → %.6g); "
                "data.max_vertices_per_loop sets the limit (null keeps every vertex, at a cost per vertex in "
                "every step and evaluation).", name, len(loop), n, before, after)
    return out


@dataclass
class PointBoundary:
    """A validated 2D boundary: points (P, 2) and signs (P,) of ±1."""

    points: np.ndarray
    signs: np.ndarray
    name: str = "points"

    def tensors(self, dtype: torch.dtype = torch.float32, device: torch.device | str = "cpu"):
        return (
            torch.as_tensor(self.points, dtype=dtype, device=device),
            torch.as_tensor(self.signs, dtype=dtype, device=device),
        )


def validate_points(points, signs, source: str = "data.points", domain: float = 1.0) -> PointBoundary:
    """Checks a 2D boundary: finite points strictly inside the domain, signs ±1 summing to zero."""
    try:  # a word or a file name where a list of numbers belongs (data.points=my_points.txt)
        pts = np.asarray(points, dtype=np.float64)
        sg = np.asarray(signs, dtype=np.float64)
    except (TypeError, ValueError):
        raise BoundaryError(f"Boundary {source} must be a list of [x, y] numbers with one sign ±1 each, e.g. "
                            "data.points=[[-0.5,0],[0.5,0]] data.signs=[-1,1].") from None
    if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) == 0:
        raise BoundaryError(f"Boundary {source} must be a non-empty list of [x, y] points, got shape {pts.shape}.")
    if sg.shape != (len(pts),) or not np.all(np.isin(sg, (-1.0, 1.0))):
        raise BoundaryError(f"Boundary {source}: signs must be one +1 or -1 per point.")
    if not np.isfinite(pts).all():
        raise BoundaryError(f"Boundary {source} has NaN or infinite coordinates.")
    if np.abs(pts).max() >= domain:
        raise BoundaryError(f"Boundary {source} has points outside the domain [-{domain:g}, {domain:g}]^2.")
    if sg.sum() != 0:
        raise BoundaryError(
            f"Boundary {source}: signs must sum to zero (every curve starts at a -1 point and ends at a +1 point)."
        )
    if len(pts) > 1 and (np.linalg.norm(pts[:, None] - pts[None], axis=-1) + np.eye(len(pts))).min() < 1e-9:
        raise BoundaryError(f"Boundary {source} has coincident points.")
    return PointBoundary(pts, sg)


def polyline_length(loops: list[np.ndarray]) -> float:
    """Total length of closed polygonal loops."""
    return float(sum(np.linalg.norm(np.roll(lp, -1, 0) - lp, axis=1).sum() for lp in loops))
