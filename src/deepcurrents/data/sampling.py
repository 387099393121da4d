"""Samples of U = [-1, 1]^d for the current loss E_x|ω(x)|, and the weights that keep the loss an unbiased
estimate of that uniform mean whatever the sampling density.

- ``uniform``: i.i.d. uniform samples, weight 1 (the paper's).
- ``sobol``: scrambled Sobol points (torch.quasirandom.SobolEngine), weight 1: the same expectation with
  less clumping, so a lower-variance estimate of the mass per batch.
- ``importance``: a mixture of uniform samples (a fraction ``uniform_fraction`` of each batch) and samples
  from a grid of ``resolution^d`` cells drawn with probability ∝ score^power (score: |α_Γ| near each cell
  centre, so cells around Γ, where |α| ~ 1/r, get more samples). With the batch's mixture density q,
  weight w(x) = 1 / (vol(U) q(x)) = 1 / (u + (1 − u) C p_c), so E_q[w |ω|] = E_uniform[|ω|]: the loss is
  still the mass (the balance-heuristic estimator of multiple importance sampling, exact with fixed counts).
  The final mass bound is evaluated without these scores all the same (eval.metrics.mass_estimate: stratified
  uniform samples, and a tube about Γ sampled by a density fixed by Γ alone).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import torch
from scipy.spatial import cKDTree

from deepcurrents.errors import ConfigError, number_at_least, share

SAMPLING_KINDS = ("uniform", "sobol", "importance")


def cell_centres(dim: int, resolution: int) -> torch.Tensor:
    """Centres of the resolution^dim cubic cells of [-1, 1]^dim, row-major (last axis fastest). → (C, dim)."""
    h = 2.0 / resolution
    axis = -1.0 + h * (torch.arange(resolution, dtype=torch.float64) + 0.5)
    grids = torch.meshgrid(*([axis] * dim), indexing="ij")
    return torch.stack(grids, -1).reshape(-1, dim).float()


def cell_scores(field: Callable[[torch.Tensor], torch.Tensor], dim: int, resolution: int,
                points_per_cell: int = 8, seed: int = 0) -> torch.Tensor:
    """Mean of |field| at ``points_per_cell`` random points of each cell: a coarse picture of where the
    integrand is large. field: (N, dim) → (N, k). → (C,) non-negative."""
    gen = torch.Generator().manual_seed(seed)
    centres = cell_centres(dim, resolution)
    h = 2.0 / resolution
    offsets = (torch.rand(points_per_cell, 1, dim, generator=gen) - 0.5) * h
    points = (centres[None] + offsets).reshape(-1, dim)
    values = torch.cat([field(chunk).norm(dim=-1) for chunk in torch.split(points, 1 << 15)])
    values = torch.nan_to_num(values.reshape(points_per_cell, -1).double(), nan=0.0, posinf=0.0)
    return values.mean(0).float()


class AmbientSampler:
    """Draws batches {"x": (n, dim)[, "weight": (n,)]} of U = [-1, 1]^dim (see the module's docstring).

    Args:
        dim: 2 or 3.
        kind: "uniform", "sobol" or "importance".
        seed: the stream's seed (Sobol scrambling, cell and offset draws).
        resolution: cells per axis of the importance grid.
        uniform_fraction: u, the share of each batch drawn uniformly (keeps every weight ≤ 1/u).
        power: cell probability ∝ score^power (1: ∝ the coarse |ω|, the estimator-variance optimum for the
            loss; smaller flattens it).
        scores: (resolution^dim,) non-negative cell scores (importance only; set_scores changes them).
    """

    def __init__(self, dim: int, kind: str = "uniform", seed: int = 0, resolution: int = 16,
                 uniform_fraction: float = 0.5, power: float = 1.0, scores: torch.Tensor | None = None):
        self.dim, self.kind, self.resolution = dim, kind, resolution
        self.uniform_fraction, self.power = float(uniform_fraction), float(power)
        self.generator = torch.Generator().manual_seed(seed)
        self.sobol = torch.quasirandom.SobolEngine(dim, scramble=True, seed=seed) if kind != "uniform" else None
        self.probs = torch.full((resolution**dim,), 1.0 / resolution**dim)
        if scores is not None:
            self.set_scores(scores)

    @property
    def num_cells(self) -> int:
        return self.resolution**self.dim

    def set_scores(self, scores: torch.Tensor) -> None:
        """Cell probabilities ∝ scores^power. scores: (resolution^dim,) ≥ 0 (all zero: uniform cells)."""
        scores = torch.as_tensor(scores, dtype=torch.float64).flatten()
        if scores.numel() != self.num_cells:
            raise ValueError(f"expected {self.num_cells} cell scores, got {scores.numel()}")
        s = torch.nan_to_num(scores.clamp_min(0.0), nan=0.0, posinf=0.0) ** self.power
        total = float(s.sum())
        self.probs = (s / total if total > 0 else torch.full_like(s, 1.0 / s.numel())).float()

    def _uniform(self, n: int) -> torch.Tensor:
        if self.sobol is not None:
            return self.sobol.draw(n).float() * 2.0 - 1.0
        return torch.rand(n, self.dim, generator=self.generator) * 2.0 - 1.0

    def density(self, x: torch.Tensor, uniform_share: float | None = None) -> torch.Tensor:
        """vol(U) × the sampling density at x (1 for uniform and Sobol); ``uniform_share`` defaults to
        uniform_fraction. (N, dim) → (N,)."""
        if self.kind != "importance":
            return torch.ones(x.shape[0])
        u = self.uniform_fraction if uniform_share is None else uniform_share
        return u + (1.0 - u) * self.num_cells * self.probs[self.cell_index(x)]

    def cell_index(self, x: torch.Tensor) -> torch.Tensor:
        """Index of the cell holding each point. (N, dim) → (N,) long."""
        idx = ((x + 1.0) * (self.resolution / 2.0)).floor().long().clamp_(0, self.resolution - 1)
        flat = torch.zeros(x.shape[0], dtype=torch.long)
        for axis in range(self.dim):
            flat = flat * self.resolution + idx[:, axis]
        return flat

    def sample(self, n: int) -> dict[str, torch.Tensor]:
        """One batch of n points; "weight" only for importance sampling. → {"x": (n, dim), "weight": (n,)}."""
        if self.kind != "importance":
            return {"x": self._uniform(n)}
        n_uniform = round(self.uniform_fraction * n) if self.uniform_fraction < 1.0 else n
        n_cells = n - n_uniform
        parts = [self._uniform(n_uniform)] if n_uniform else []
        if n_cells:
            cells = torch.multinomial(self.probs, n_cells, replacement=True, generator=self.generator)
            h = 2.0 / self.resolution
            corner = torch.stack([(cells // self.resolution**(self.dim - 1 - a)) % self.resolution
                                  for a in range(self.dim)], -1).float() * h - 1.0
            parts.append(corner + torch.rand(n_cells, self.dim, generator=self.generator) * h)
        x = torch.cat(parts)
        # the realised share n_uniform / n: with fixed counts the weights are then exact
        return {"x": x, "weight": 1.0 / self.density(x, n_uniform / n)}


def mesh_cell_scores(mesh, resolution: int, spread: int = 1) -> np.ndarray:
    """Probabilities (resolution³,) of the cells of [-1, 1]³ (row-major, as ``AmbientSampler``) ∝ the area of a
    trimesh ``mesh`` whose face centres fall in them, averaged over each cell's (2·spread + 1)³ neighbourhood
    (the shell around a sheet reaches the next cells)."""
    from scipy.ndimage import uniform_filter

    h = 2.0 / resolution
    idx = np.clip(((np.asarray(mesh.triangles_center) + 1.0) / h).astype(np.int64), 0, resolution - 1)
    grid = np.zeros((resolution,) * 3)
    np.add.at(grid, (idx[:, 0], idx[:, 1], idx[:, 2]), np.asarray(mesh.area_faces))
    if spread > 0:
        grid = np.maximum(uniform_filter(grid, size=2 * spread + 1, mode="constant"), 0.0)  # no rounding below 0
    total = grid.sum()
    return (grid / total).ravel() if total > 0 else np.full(grid.size, 1.0 / grid.size)


def mesh_sampler(mesh, seed: int = 0, resolution: int = 64, uniform_fraction: float = 0.1) -> AmbientSampler:
    """Importance samples of [-1, 1]³ concentrated in the cells around a mesh (``mesh_cell_scores``), with the
    weights 1/q that keep weighted means unbiased estimates of uniform ones (the sharpened area bound)."""
    return AmbientSampler(3, "importance", seed=seed, resolution=resolution, uniform_fraction=uniform_fraction,
                          scores=torch.as_tensor(mesh_cell_scores(mesh, resolution)))


def sampling_options(sampling: dict | None) -> dict:
    """``data.sampling`` checked (unknown keys named). → keyword arguments of AmbientSampler (without dim)."""
    sampling = dict(sampling or {})
    unknown = set(sampling) - {"kind", "resolution", "uniform_fraction", "power", "pool"}
    if unknown:
        raise ConfigError(f"data.sampling has unknown keys {sorted(unknown)}; it takes kind, resolution, "
                          "uniform_fraction, power and pool.")
    sampling["pool"] = sampling.get("pool") or 0  # its value, like the others', is checked by experiments.schema
    return sampling


def sample_pool(sampler: AmbientSampler, size: int, field: Callable[[torch.Tensor], torch.Tensor],
                chunk: int = 1 << 14) -> dict[str, torch.Tensor]:
    """``size`` samples drawn once with ``field`` (e.g. the unscaled α_Γ) evaluated at them, so that training
    steps draw batches from this pool and never evaluate the field (α is fixed for a fixed Γ).
    → {"x": (size, dim), "alpha": (size, k)[, "weight": (size,)]}."""
    batch = sampler.sample(size)
    with torch.no_grad():
        batch["alpha"] = torch.cat([field(c) for c in torch.split(batch["x"], chunk)])
    return batch


def pool_batch(pool: dict[str, torch.Tensor], n: int, generator: torch.Generator) -> dict[str, torch.Tensor]:
    """n rows of a pool drawn uniformly with replacement (so weights stay those of the pool's density)."""
    idx = torch.randint(pool["x"].shape[0], (n,), generator=generator)
    return {k: v[idx] for k, v in pool.items()}



# ------------------------------------------------------------------------------------------ near a target

NEAR_SAMPLING_KINDS = ("uniform", "near")


def truncated_gaussian_mass(radius: float, dim: int = 3) -> float:
    """P(|z| ≤ radius) for z ~ N(0, I_dim), dim 2 or 3 (the normalising constant of a Gaussian cut at
    ``radius`` standard deviations)."""
    if dim == 2:
        return 1.0 - math.exp(-0.5 * radius * radius)
    if dim == 3:
        return math.erf(radius / math.sqrt(2.0)) - math.sqrt(2.0 / math.pi) * radius * math.exp(-0.5 * radius**2)
    raise ValueError(f"dim must be 2 or 3, got {dim}")


class NearTargetSampler:
    """Ambient samples of U = [-domain, domain]^d concentrated near a target Σ, with the weights that keep
    the current loss an unbiased estimate of its uniform mean E_{x~U}[g(x)].

    Reconstruction's metric only acts near the target (far away any surface with the target's normals is
    free), so uniform samples spend most of a batch where the loss has nothing to say. Each batch has a
    fixed count n_u = round(uniform_fraction · n) of uniform samples and n − n_u samples
    y_k + σ z, y_k drawn uniformly from K fixed ``anchors`` on Σ and z ~ N(0, I) cut at |z| ≤ ``radius``.
    Its mixture density is exact (a finite sum over the anchors within radius·σ):

        q(x) = (n_u / n) · 1_U(x) / vol(U) + (1 − n_u / n) · (1/K) Σ_k φ(x − y_k),

    φ the cut Gaussian's density, and the weight w(x) = 1_U(x) / (vol(U) q(x)) makes (1/n) Σ_i w(x_i) g(x_i)
    an unbiased estimate of E_U[g] (the balance heuristic with fixed counts; a near sample outside U gets
    weight 0). With ``weighted=False`` every weight is 1: the loss then stresses the shell around Σ (a
    different objective, kept for comparison).

    Args:
        anchors: (K, d) points on Σ (e.g. uniform surface samples drawn once).
        sigma: σ of the Gaussians around the anchors (model units; the target fits in [-0.5, 0.5]^3).
        uniform_fraction: share of each batch drawn uniformly in U, in (0, 1] (bounds every weight by 1/u).
        domain: half-side of U.
        radius: where the Gaussians are cut, in σ (3: 97 % of a 3D Gaussian's mass).
        weighted: importance weights (True) or all ones.
    """

    def __init__(self, anchors: np.ndarray, sigma: float, uniform_fraction: float = 0.5, domain: float = 1.0,
                 radius: float = 3.0, weighted: bool = True):
        number_at_least("data.sampling.near_sigma", sigma, strict=True)
        share("data.sampling.uniform_fraction", uniform_fraction, "a uniform share bounds the importance weights")
        self.anchors = np.ascontiguousarray(np.asarray(anchors, np.float64))
        if self.anchors.ndim != 2 or len(self.anchors) == 0:
            raise ValueError("anchors must be a non-empty (K, d) array")
        self.dim = self.anchors.shape[1]
        self.sigma, self.uniform_fraction, self.domain = float(sigma), float(uniform_fraction), float(domain)
        self.radius, self.weighted = float(radius), bool(weighted)
        self.tree = cKDTree(self.anchors)
        self._norm = 1.0 / ((2.0 * math.pi) ** (self.dim / 2) * self.sigma**self.dim
                            * truncated_gaussian_mass(self.radius, self.dim))

    def near_density(self, x: np.ndarray) -> np.ndarray:
        """(1/K) Σ_k φ(x − y_k), the density of the near samples. (N, d) → (N,) float64."""
        x = np.asarray(x, np.float64)
        pairs = cKDTree(x).sparse_distance_matrix(self.tree, self.radius * self.sigma, output_type="ndarray")
        # "ndarray" output keeps pairs at distance 0 (a sparse matrix would drop them as zeros)
        kernel = np.exp(-0.5 * (pairs["v"] / self.sigma) ** 2)
        return np.bincount(pairs["i"], weights=kernel, minlength=len(x)) * (self._norm / len(self.anchors))

    def weight(self, x: np.ndarray, uniform_share: float) -> np.ndarray:
        """w(x) = 1_U(x) / (vol(U) q(x)) for a batch whose uniform share is ``uniform_share``. (N, d) → (N,)."""
        x = np.asarray(x, np.float64)
        inside = (np.abs(x) <= self.domain).all(1)
        volume = (2.0 * self.domain) ** self.dim
        q_vol = uniform_share * inside + (1.0 - uniform_share) * volume * self.near_density(x)
        return np.where(inside, 1.0 / np.maximum(q_vol, 1e-300), 0.0)

    def sample(self, n: int, generator: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
        """n samples, uniform first, and their weights. → (x (n, d) float64, weight (n,) float64)."""
        n_uniform = round(self.uniform_fraction * n) if self.uniform_fraction < 1.0 else n
        n_near = n - n_uniform
        x = (torch.rand(n, self.dim, generator=generator, dtype=torch.float64) * 2.0 - 1.0) * self.domain
        if n_near:
            k = torch.randint(len(self.anchors), (n_near,), generator=generator).numpy()
            z = torch.randn(n_near, self.dim, generator=generator, dtype=torch.float64)
            while True:  # cut at |z| ≤ radius: redraw the few outside (1 in 34 at radius 3)
                out = z.norm(dim=1) > self.radius
                if not out.any():
                    break
                z[out] = torch.randn(int(out.sum()), self.dim, generator=generator, dtype=torch.float64)
            x[n_uniform:] = torch.as_tensor(self.anchors[k]) + self.sigma * z
        if not self.weighted:
            return x, torch.ones(n, dtype=torch.float64)
        return x, torch.as_tensor(self.weight(x.numpy(), n_uniform / n))
