"""Volume rendering of neural currents (the paper's pictures): density from |ω|, colour from ω's direction.

A current ω = ∇f + alpha_scale·α concentrates on its surface as ``jump · alpha_scale · n · δ_Σ``
(jump = 4π in 3D), so we render the density

    σ(x) = gain · max(|ω(x)| − floor, 0) / (jump · alpha_scale)          [1 / length]

whose integral across an ideal sheet is ``gain``: a face-on sheet has opacity 1 − exp(−gain), whatever the
network's bandwidth, and the weak residual |ω| away from the surface (below ``floor``) stays transparent.
Each sample emits the paper's orientation colour ``plots.normal_colors(ω)``.

Sampling (the sheet is thin: uniform ray marching would need thousands of samples per ray):

1. a *proposal grid*: |ω| on a coarse grid over the domain, then on a finer grid over the part where the
   current lives (its *support* box), max-dilated by one cell so that a sheet between nodes is not lost;
   computed once and shared by every frame of a turntable;
2. per ray, the proposal's trilinear interpolation on ``proposal_bins`` bins inside the support box, mixed
   with a uniform share (defensive importance sampling), gives a piecewise-constant pdf; its quantiles
   ``(k + ½)/K`` place the K samples (deterministic: no flicker between frames);
3. ω is evaluated exactly at the samples (those in grid cells whose dilated nodes are all at or below the
   floor get σ = 0 without it) and composited front to back over the partition of the ray by the samples'
   midpoints (so a uniform fog still gets its exact optical depth).

Everything runs on the current's device, rays in chunks. Boundary curves are drawn over the image with a
depth test against the volume (dimmed where the surface hides them).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from deepcurrents.errors import ConfigError, UserInputError
from deepcurrents.eval.device import device_of
from deepcurrents.eval.metrics import jump
from deepcurrents.eval.plots import normal_colors
from deepcurrents.eval.render.camera import Camera, fit_camera
from deepcurrents.geometry.polyline import closed_loop_segments, resample_polyline

log = logging.getLogger(__name__)

DOMAIN = np.array([[-1.0] * 3, [1.0] * 3])


# ------------------------------------------------------------------------------------------ the density
@dataclass
class DensitySettings:
    """How |ω| becomes opacity: σ = gain · max(|ω| − floor, 0) / (jump · alpha_scale)."""

    gain: float = 3.0
    floor: float = 2.5e-3
    shading: float = 0.0  # 0: pure orientation colour; s > 0: × (1 − s + s·|ω̂·view|), a headlight

    def __post_init__(self):
        if not self.gain > 0:
            raise ConfigError(f"gain={self.gain!r} must be positive.")
        if not self.floor >= 0:
            raise ConfigError(f"floor={self.floor!r} must be non-negative.")
        if not 0 <= self.shading <= 1:
            raise ConfigError(f"shading={self.shading!r} must be in [0, 1].")


@dataclass
class ProposalGrid:
    """|ω| on a regular grid over ``bounds`` (max-dilated by one cell), the box where the current lives
    (``support``: rays are marched there) and the points a camera frames (``frame``: Γ and the grid
    nodes where the current is clearly visible).

    values (G0, G1, G2) on the current's device; bounds, support (2, 3); frame (N, 3); support and
    frame are None if the current is empty (|ω| below the floor everywhere and no Γ).
    """

    values: torch.Tensor
    bounds: np.ndarray
    support: np.ndarray | None
    frame: np.ndarray | None = None

    def framing_points(self) -> np.ndarray:
        """The points (N, 3) cameras are fitted to (the domain's corners for an empty current)."""
        for pts in (self.frame, self.support):
            if pts is not None:
                return pts
        return DOMAIN

    def lookup(self, x: torch.Tensor) -> torch.Tensor:
        """Trilinear interpolation at points (N, 3) → (N,) (zero outside the grid)."""
        lo = torch.as_tensor(self.bounds[0], dtype=x.dtype, device=x.device)
        hi = torch.as_tensor(self.bounds[1], dtype=x.dtype, device=x.device)
        g = (x - lo) / (hi - lo) * 2.0 - 1.0
        # grid_sample wants (x, y, z) ↔ (W, H, D): values are indexed [i, j, k] ↔ (x, y, z), so flip
        grid = g.flip(-1).reshape(1, -1, 1, 1, 3)
        out = F.grid_sample(self.values[None, None], grid, mode="bilinear", padding_mode="zeros",
                            align_corners=True)
        return out.reshape(-1)

    def above(self, x: torch.Tensor, floor: float) -> torch.Tensor:
        """Whether a node of the grid cell holding each point (N, 3) has a value above ``floor`` → (N,) bool
        (True outside the grid). Values are max-dilated by a cell, so False means that |ω| is at most the
        floor at every node within a cell of the point's own, the assumption the proposal makes already."""
        lo = torch.as_tensor(self.bounds[0], dtype=x.dtype, device=x.device)
        hi = torch.as_tensor(self.bounds[1], dtype=x.dtype, device=x.device)
        cells = torch.as_tensor(self.values.shape, device=x.device) - 1
        u = (x - lo) / (hi - lo) * cells
        inside = ((u >= 0) & (u <= cells)).all(-1)
        i = torch.minimum(u.clamp_min(0).long(), cells - 1)
        cell_max = F.max_pool3d(self.values[None, None], kernel_size=2, stride=1)[0, 0]  # max of each cell's corners
        return ~inside | (cell_max[i[:, 0], i[:, 1], i[:, 2]] > floor)


def _grid_points(bounds: np.ndarray, resolution: int) -> tuple[np.ndarray, tuple[int, int, int]]:
    extent = bounds[1] - bounds[0]
    step = float(extent.max()) / (resolution - 1)
    shape = tuple(int(max(2, math.ceil(e / step - 1e-9) + 1)) for e in extent)
    axes = [np.linspace(bounds[0, i], bounds[1, i], shape[i]) for i in range(3)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3), shape


@torch.no_grad()
def _omega_norm_grid(current, bounds: np.ndarray, resolution: int, chunk_size: int):
    pts, shape = _grid_points(bounds, resolution)
    x = torch.as_tensor(pts, dtype=torch.float32, device=device_of(current))
    _, omega = current.evaluate(x, chunk_size=chunk_size)
    vol = omega.norm(dim=-1).reshape(shape)
    dilated = F.max_pool3d(vol[None, None], kernel_size=3, stride=1, padding=1)[0, 0]
    return dilated, shape


def _support_box(values: torch.Tensor, bounds: np.ndarray, floor: float,
                 keep: float = 0.995) -> np.ndarray | None:
    """The box holding the bulk of the visible density max(|ω| − floor, 0) on a grid (values (G0, G1, G2)
    over ``bounds``): per axis, the quantiles (1 − keep)/2 and (1 + keep)/2 of its marginal, grown by a
    cell. Specks of stray |ω| (the network's edges of the domain) hold little mass and stay out."""
    density = (values - floor).clamp_min(0.0).double()
    total = float(density.sum())
    if total <= 0:
        return None
    shape = np.array(values.shape)
    cell = (bounds[1] - bounds[0]) / (shape - 1)
    lo, hi = np.empty(3), np.empty(3)
    for axis in range(3):
        others = tuple(a for a in range(3) if a != axis)
        cdf = (density.sum(dim=others).cumsum(0) / total).cpu().numpy()
        first = int(np.searchsorted(cdf, 0.5 * (1 - keep)))
        last = int(np.searchsorted(cdf, 0.5 * (1 + keep)))
        lo[axis] = bounds[0, axis] + (first - 1) * cell[axis]
        hi[axis] = bounds[0, axis] + (min(last, shape[axis] - 1) + 1) * cell[axis]
    return np.stack([np.maximum(lo, bounds[0]), np.minimum(hi, bounds[1])])


@torch.no_grad()
def proposal_grid(current, resolution: int = 48, settings: DensitySettings | None = None,
                  bounds: np.ndarray | None = None, chunk_size: int = 1 << 15) -> ProposalGrid:
    """The proposal grid of a 3D current.

    A (resolution/2)³ grid of |ω| over ``bounds`` (default the domain [-1, 1]³) finds the *support*: the
    box holding 99.5% of the visible density max(|ω| − floor, 0) (dilated by a cell), grown to hold Γ
    (the surface's border lies on it); then a grid with ``resolution`` nodes along the support's longest
    side samples |ω| there for the proposal. A sheet thinner than the coarse spacing can fall between
    nodes: Γ's box still holds minimal surfaces; raise ``resolution`` for thin sheets far from Γ.
    """
    if isinstance(resolution, bool) or not isinstance(resolution, (int, np.integer)) or resolution < 4:
        raise ConfigError(f"grid={resolution!r} must be an integer ≥ 4.")
    settings = settings or DensitySettings()
    bounds = DOMAIN.copy() if bounds is None else np.asarray(bounds, dtype=np.float64)
    threshold = settings.floor if settings.floor > 0 else 1e-9
    coarse, _ = _omega_norm_grid(current, bounds, max(4, int(resolution) // 2), chunk_size)
    support = _support_box(coarse, bounds, threshold)
    loops = getattr(current, "loops", None)
    gamma = (torch.cat([lp.detach().reshape(-1, 3) for lp in loops]).cpu().double().numpy() if loops
             else np.zeros((0, 3)))
    if len(gamma):
        cell = float((bounds[1] - bounds[0]).max()) / (max(4, int(resolution) // 2) - 1)
        support = _union(support, np.stack([gamma.min(0) - cell, gamma.max(0) + cell]), bounds)
    if support is None:
        return ProposalGrid(coarse, bounds, None)
    fine, _ = _omega_norm_grid(current, support, int(resolution), chunk_size)
    # frame what is clearly visible (twice the floor, on the undilated side of the blur) and Γ
    nodes, _ = _grid_points(support, int(resolution))
    seen = nodes[(fine >= 2.0 * threshold).reshape(-1).cpu().numpy()]
    frame = np.concatenate([seen[:: max(1, len(seen) // 4096)], gamma])
    return ProposalGrid(fine, support, support, frame if len(frame) else None)


def _union(box: np.ndarray | None, other: np.ndarray, bounds: np.ndarray) -> np.ndarray:
    """The box holding two boxes (2, 3), clipped to ``bounds``."""
    if box is not None:
        other = np.stack([np.minimum(box[0], other[0]), np.maximum(box[1], other[1])])
    return np.stack([np.maximum(other[0], bounds[0]), np.minimum(other[1], bounds[1])])


# -------------------------------------------------------------------------------------------- rendering
@dataclass
class Rendering:
    """A rendered image: premultiplied colour (H, W, 3), opacity (H, W) and the distance from the eye at
    which the opacity along each ray reaches ½ (H, W; +inf where it never does), all float numpy."""

    color: np.ndarray
    alpha: np.ndarray
    depth: np.ndarray

    def over(self, background: Sequence[float] = (1.0, 1.0, 1.0)) -> np.ndarray:
        """Composited over a background colour → (H, W, 3) uint8."""
        bg = np.asarray(background, dtype=np.float64)
        rgb = self.color + (1.0 - self.alpha[..., None]) * bg
        return np.clip(np.round(rgb * 255.0), 0, 255).astype(np.uint8)

    def rgba(self) -> np.ndarray:
        """Straight (non-premultiplied) RGBA → (H, W, 4) uint8, transparent background."""
        a = self.alpha[..., None]
        rgb = np.where(a > 1e-6, self.color / np.maximum(a, 1e-6), 0.0)
        return np.clip(np.round(np.concatenate([rgb, a], -1) * 255.0), 0, 255).astype(np.uint8)


def _box_intersection(origins: torch.Tensor, dirs: torch.Tensor, box: np.ndarray):
    """Slab test: (t_near (R,), t_far (R,), hit (R,)) of rays against an axis-aligned box (2, 3)."""
    lo = torch.as_tensor(box[0], dtype=origins.dtype, device=origins.device)
    hi = torch.as_tensor(box[1], dtype=origins.dtype, device=origins.device)
    inv = 1.0 / torch.where(dirs.abs() < 1e-12, torch.full_like(dirs, 1e-12), dirs)
    t0, t1 = (lo - origins) * inv, (hi - origins) * inv
    t_near = torch.minimum(t0, t1).amax(-1).clamp_min(0.0)
    t_far = torch.maximum(t0, t1).amin(-1)
    return t_near, t_far, t_far > t_near


def _sample_along(t_near: torch.Tensor, t_far: torch.Tensor, pdf: torch.Tensor, count: int) -> torch.Tensor:
    """Quantiles (k + ½)/count of a piecewise-constant pdf on equal bins of [t_near, t_far] per ray.

    pdf (R, B) non-negative, rows summing to 1 → t (R, count), increasing along each row.
    """
    rays, bins = pdf.shape
    cdf = torch.cat([torch.zeros(rays, 1, device=pdf.device, dtype=pdf.dtype), pdf.cumsum(-1)], -1)
    cdf[:, -1] = 1.0
    u = (torch.arange(count, device=pdf.device, dtype=pdf.dtype) + 0.5) / count
    u = u.expand(rays, count).contiguous()
    idx = torch.searchsorted(cdf, u, right=True).clamp(1, bins)
    c0, c1 = cdf.gather(1, idx - 1), cdf.gather(1, idx)
    frac = ((u - c0) / (c1 - c0).clamp_min(1e-12)).clamp(0.0, 1.0)
    s = (idx - 1 + frac) / bins  # position in [0, 1] along the segment
    return t_near[:, None] + s * (t_far - t_near)[:, None]


@torch.no_grad()
def _render_rays(current, origins, dirs, grid: ProposalGrid, settings: DensitySettings, samples: int,
                 proposal_bins: int, uniform_share: float, chunk_size: int):
    """Composites R rays → (premultiplied colour (R, 3), opacity (R,), depth (R,))."""
    rays = origins.shape[0]
    color = torch.zeros(rays, 3, device=origins.device)
    alpha = torch.zeros(rays, device=origins.device)
    depth = torch.full((rays,), float("inf"), device=origins.device)
    if grid.support is None:
        return color, alpha, depth
    t_near, t_far, hit = _box_intersection(origins, dirs, grid.support)
    if not bool(hit.any()):
        return color, alpha, depth
    o, d, tn, tf = origins[hit], dirs[hit], t_near[hit], t_far[hit]
    n = o.shape[0]
    # 1. proposal pdf on equal bins from the (dilated) grid
    centres = (torch.arange(proposal_bins, device=o.device, dtype=o.dtype) + 0.5) / proposal_bins
    tb = tn[:, None] + centres[None] * (tf - tn)[:, None]
    prop = grid.lookup((o[:, None] + tb[..., None] * d[:, None]).reshape(-1, 3)).reshape(n, proposal_bins)
    total = prop.sum(-1, keepdim=True)
    prop = torch.where(total > 0, prop / total.clamp_min(1e-30), torch.full_like(prop, 1.0 / proposal_bins))
    pdf = (1.0 - uniform_share) * prop + uniform_share / proposal_bins
    # 2. samples at the pdf's quantiles, exact ω there
    t = _sample_along(tn, tf, pdf, samples)  # (n, K)
    x = (o[:, None] + t[..., None] * d[:, None]).reshape(-1, 3)
    # ω only where the grid says the density can be positive (about half the samples of the make-run trefoil:
    # the uniform share, and rays that miss the sheet); elsewhere σ = 0 as |ω| ≤ floor there
    visible = grid.above(x, settings.floor)
    omega = torch.zeros(x.shape[0], 3, device=x.device)
    if bool(visible.any()):
        omega[visible] = current.evaluate(x[visible], chunk_size=chunk_size)[1].float()
    omega = omega.reshape(n, samples, 3)
    norm = omega.norm(dim=-1)
    sigma = settings.gain * (norm - settings.floor).clamp_min(0.0) / (jump(3) * float(current.alpha_scale))
    # 3. front-to-back compositing over the midpoint partition of [t_near, t_far]
    edges = torch.cat([tn[:, None], 0.5 * (t[:, 1:] + t[:, :-1]), tf[:, None]], -1)
    a = 1.0 - torch.exp(-sigma * (edges[:, 1:] - edges[:, :-1]))
    trans = torch.cumprod(torch.cat([torch.ones(n, 1, device=a.device), 1.0 - a[:, :-1]], -1), -1)
    w = trans * a  # (n, K)
    rgb = torch.as_tensor(normal_colors(omega.reshape(-1, 3).cpu().double().numpy()), dtype=torch.float32,
                          device=o.device).reshape(n, samples, 3)
    if settings.shading > 0:
        facing = (omega * d[:, None]).sum(-1).abs() / norm.clamp_min(1e-12)
        rgb = rgb * (1.0 - settings.shading + settings.shading * facing)[..., None]
    color[hit] = (w[..., None] * rgb).sum(1)
    acc = w.sum(-1)
    alpha[hit] = acc
    reached = (1.0 - trans * (1.0 - a)) >= 0.5  # opacity after sample k
    first = reached.float().argmax(-1)
    depth[hit] = torch.where(reached.any(-1), t.gather(1, first[:, None]).squeeze(1),
                             torch.full_like(tn, float("inf")))
    return color, alpha, depth


@torch.no_grad()
def render_current(
    current,
    camera: Camera | None = None,
    samples: int = 64,
    grid: ProposalGrid | int = 48,
    settings: DensitySettings | None = None,
    proposal_bins: int = 128,
    uniform_share: float = 0.1,
    ray_chunk: int = 4096,
    chunk_size: int = 1 << 15,
    curves: bool = True,
    curve_width: float = 2.0,
) -> Rendering:
    """Volume render of a 3D current (see the module docstring).

    Args:
        current: a NeuralCurrent-like module: ``evaluate(x, chunk_size) -> (f (N,), ω (N, 3))``,
            ``alpha_scale``, and ``loops`` (list of (M_i, 3)) for the boundary curves.
        camera: None fits a camera at the default angles around the current's support.
        samples: ω evaluations per ray.
        grid: a ProposalGrid (reuse it across frames) or the resolution of a new one.
        curves: draw Γ over the image.

    Raises UserInputError when the camera sees nothing of the current's support.
    """
    if isinstance(samples, bool) or not isinstance(samples, int) or samples < 2:
        raise ConfigError(f"samples={samples!r} must be an integer ≥ 2.")
    settings = settings or DensitySettings()
    if not isinstance(grid, ProposalGrid):
        grid = proposal_grid(current, int(grid), settings, chunk_size=chunk_size)
    if camera is None:
        camera = fit_camera(grid.framing_points())
    h, w = camera.height, camera.width
    dev = device_of(current)
    origins, dirs = camera.rays(dev)
    if grid.support is None:
        log.warning("The current is empty (|ω| < %.3g everywhere): the image is blank.", settings.floor)
    elif not bool(_box_intersection(origins, dirs, grid.support)[2].any()):
        raise UserInputError(
            f"The camera (azimuth {camera.azimuth}, elevation {camera.elevation}, "
            f"distance {camera.distance}, target {tuple(camera.target)}) sees nothing of the current, "
            f"which lives in the box "
            f"{np.round(grid.support, 3).tolist()}."
        )
    parts = [_render_rays(current, o, d, grid, settings, samples, proposal_bins, uniform_share, chunk_size)
             for o, d in zip(torch.split(origins, ray_chunk), torch.split(dirs, ray_chunk), strict=True)]
    color, alpha, depth = (torch.cat(p).cpu().double().numpy() for p in zip(*parts, strict=True))
    image = Rendering(color.reshape(h, w, 3), alpha.reshape(h, w), depth.reshape(h, w))
    loops = getattr(current, "loops", None)
    if curves and loops:
        draw_curves(image, camera, [lp.detach().cpu().double().numpy() for lp in loops], width=curve_width)
    return image


def draw_curves(image: Rendering, camera: Camera, loops: Sequence[np.ndarray], width: float = 2.0,
                color: Sequence[float] = (0.0, 0.0, 0.0), hidden: float = 0.3,
                tolerance: float = 0.1) -> None:
    """Draws closed polylines (M_i, 3) into ``image`` in place: opaque where nearer than the volume's
    depth + ``tolerance`` (Γ lies on the surface's border, inside the halo where α dominates the smooth
    network), blended with weight ``hidden`` where the surface is clearly in front."""
    if not loops:
        return
    h, w = image.alpha.shape
    starts, ends, _ = closed_loop_segments(loops)
    # world spacing of about ⅓ pixel at the target's distance
    spacing = camera.distance / camera.focal / 3.0
    pts = resample_polyline(starts, ends, spacing)
    col, row, dist = camera.project(pts)
    ok = np.isfinite(col)
    col, row, dist = col[ok], row[ok], dist[ok]
    r = max(0.5, 0.5 * width)
    k = int(math.ceil(r))
    off = np.stack(np.meshgrid(np.arange(-k, k + 1), np.arange(-k, k + 1), indexing="ij"), -1).reshape(-1, 2)
    off = off[(off**2).sum(1) <= r * r + 0.25]
    ri = (np.round(row)[:, None] + off[None, :, 0]).astype(np.int64).reshape(-1)
    ci = (np.round(col)[:, None] + off[None, :, 1]).astype(np.int64).reshape(-1)
    di = np.repeat(dist, len(off))
    inside = (ri >= 0) & (ri < h) & (ci >= 0) & (ci < w)
    ri, ci, di = ri[inside], ci[inside], di[inside]
    nearest = np.full((h, w), np.inf)
    np.minimum.at(nearest, (ri, ci), di)  # the curve's own z-buffer: one depth per pixel
    mask = np.isfinite(nearest)
    visible = mask & (nearest <= image.depth + tolerance)
    weight = np.where(visible, 1.0, hidden) * mask
    c = np.asarray(color, dtype=np.float64)
    image.color[:] = (1 - weight[..., None]) * image.color + weight[..., None] * c
    image.alpha[:] = (1 - weight) * image.alpha + weight

