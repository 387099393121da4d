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
  The final mass bound is evaluated with uniform samples all the same (eval.metrics.mass_estimate).
"""

from __future__ import annotations

from collections.abc import Callable

import torch

from deepcurrents.errors import ConfigError

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
        if kind not in SAMPLING_KINDS:
            raise ConfigError(f"data.sampling.kind={kind!r} must be one of {', '.join(SAMPLING_KINDS)}.")
        if isinstance(resolution, bool) or not isinstance(resolution, int) or resolution < 1:
            raise ConfigError(f"data.sampling.resolution={resolution!r} must be a positive integer.")
        if not 0.0 < uniform_fraction <= 1.0:
            raise ConfigError(f"data.sampling.uniform_fraction={uniform_fraction} must be in (0, 1] "
                              "(a uniform share bounds the importance weights).")
        if not power >= 0:
            raise ConfigError(f"data.sampling.power={power} must be non-negative.")
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


def sampling_options(sampling: dict | None) -> dict:
    """``data.sampling`` checked (unknown keys named). → keyword arguments of AmbientSampler (without dim)."""
    sampling = dict(sampling or {})
    unknown = set(sampling) - {"kind", "resolution", "uniform_fraction", "power", "pool"}
    if unknown:
        raise ConfigError(f"data.sampling has unknown keys {sorted(unknown)}; it takes kind, resolution, "
                          "uniform_fraction, power and pool.")
    pool = sampling.get("pool") or 0
    if isinstance(pool, bool) or not isinstance(pool, int) or pool < 0:
        raise ConfigError(f"data.sampling.pool={pool!r} must be a non-negative integer (0: fresh samples).")
    sampling["pool"] = pool
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

