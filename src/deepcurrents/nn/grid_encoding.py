"""Multiresolution grids of learned features (Müller et al. 2022, "Instant neural graphics primitives"), pure PyTorch.

A sharp jump of f across the surface costs a global Fourier basis many frequencies and leaves ringing ("fog") in the
whole box; a grid feature is local, so the MLP can put a jump where it is needed without disturbing the rest. The
interpolation is (bi/tri)linear in x, so ∇_x of the features exists almost everywhere and the double backward that the
mass loss needs (∂/∂θ of ∇_x f) goes through autograd: gathers, products and sums, no custom kernels, CPU and GPU.
"""

from __future__ import annotations

import itertools
import math

import torch
from torch import nn

from deepcurrents.errors import ConfigError

# Spatial-hash primes of Müller et al. (the first is 1 so that, along x, neighbouring cells stay neighbours).
_PRIMES = (1, 2654435761, 805459861)


class MultiresGrid(nn.Module):
    """``levels`` grids on [-1, 1]^dim with resolutions from ``base_resolution`` to ``finest_resolution`` (geometric),
    ``features`` learned values per grid vertex, interpolated multilinearly. A level with more vertices than
    ``table_size`` is hashed into a table of that size (collisions are resolved by training, as in Instant-NGP).

    (N, dim) → (N, levels·features). Points outside [-1, 1]^dim are clamped to the boundary cells.
    """

    def __init__(self, dim: int = 3, levels: int = 8, base_resolution: int = 4, finest_resolution: int = 64,
                 features: int = 2, table_size: int = 1 << 18, init_scale: float = 1e-4, seed: int | None = None):
        super().__init__()
        if dim not in (2, 3):
            raise ConfigError(f"A grid encoding needs dim 2 or 3, got {dim}.")
        for name, value in (("levels", levels), ("base_resolution", base_resolution),
                            ("finest_resolution", finest_resolution), ("features", features),
                            ("table_size", table_size)):
            if int(value) < 1:
                raise ConfigError(f"model.grid_encoding.{name}={value} must be a positive integer.")
        if finest_resolution < base_resolution:
            raise ConfigError(f"model.grid_encoding.finest_resolution={finest_resolution} must be at least "
                              f"base_resolution={base_resolution}.")
        self.dim, self.levels, self.features = dim, int(levels), int(features)
        growth = (finest_resolution / base_resolution) ** (1.0 / max(levels - 1, 1))
        resolutions = [int(math.floor(base_resolution * growth**k + 1e-9)) for k in range(levels)]
        sizes = [min((r + 1) ** dim, int(table_size)) for r in resolutions]
        self.register_buffer("resolutions", torch.tensor(resolutions, dtype=torch.long))
        self.register_buffer("hashed", torch.tensor([(r + 1) ** dim > s for r, s in zip(resolutions, sizes,
                                                                                          strict=True)]))
        self.register_buffer("offsets", torch.tensor([0, *itertools.accumulate(sizes)], dtype=torch.long))
        self.register_buffer("sizes", torch.tensor(sizes, dtype=torch.long))
        self.register_buffer("corners", torch.tensor(list(itertools.product((0, 1), repeat=dim)), dtype=torch.long))
        gen = torch.Generator().manual_seed(seed) if seed is not None else None
        table = (torch.rand(sum(sizes), features, generator=gen) * 2.0 - 1.0) * init_scale
        self.table = nn.Parameter(table)

    @property
    def out_dim(self) -> int:
        return self.levels * self.features

    def vertex_index(self, vertex: torch.Tensor) -> torch.Tensor:
        """Row of ``table`` for integer grid vertices (N, L, C, dim) on every level → (N, L, C)."""
        res = self.resolutions.view(1, -1, 1)
        dense = torch.zeros_like(vertex[..., 0])
        for d in reversed(range(self.dim)):  # x fastest: i + (r+1)(j + (r+1)k)
            dense = dense * (res + 1) + vertex[..., d]
        hashed = torch.zeros_like(dense)
        for d in range(self.dim):
            hashed = hashed ^ (vertex[..., d] * _PRIMES[d])
        size = self.sizes.view(1, -1, 1)
        index = torch.where(self.hashed.view(1, -1, 1), hashed % size, dense)
        return index + self.offsets[:-1].view(1, -1, 1)

    def _cells(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Per level, the table rows of the 2^dim corners of x's cell (N, L, C) and x's position in it (N, L, dim),
        the latter still differentiable in x."""
        u = (x.clamp(-1.0, 1.0).unsqueeze(1) + 1.0) * (0.5 * self.resolutions.view(1, -1, 1).to(x.dtype))
        cell = torch.minimum(u.detach().floor().long(), self.resolutions.view(1, -1, 1) - 1)
        index = self.vertex_index(cell.unsqueeze(2) + self.corners.view(1, 1, *self.corners.shape))
        return index, u - cell.to(x.dtype)

    def _corner_values(self, index: torch.Tensor) -> torch.Tensor:
        """Table rows (N, L, C) → values (N, L, C, F); index_select's backward is one index_add."""
        return self.table.index_select(0, index.reshape(-1)).view(*index.shape, self.features)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        index, t = self._cells(x)
        tc = t.unsqueeze(2)
        # multilinear weights Π_d (t_d or 1 − t_d): (N, L, C)
        weights = torch.where(self.corners.view(1, 1, *self.corners.shape).bool(), tc, 1.0 - tc).prod(-1)
        return (weights.unsqueeze(-1) * self._corner_values(index)).sum(2).reshape(x.shape[0], -1)

    def features_and_jacobian(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The features (N, L·F) and their Jacobian ∂features/∂x (N, L·F, dim) in closed form, both linear in the
        table: the training step differentiates them once (in the table), not twice through the weights."""
        with torch.no_grad():
            index, t = self._cells(x)
            on = self.corners.view(1, 1, *self.corners.shape).bool()           # (1, 1, C, dim)
            factors = torch.where(on, t.unsqueeze(2), 1.0 - t.unsqueeze(2))     # (N, L, C, dim)
            half_res = (0.5 * self.resolutions.to(x.dtype)).view(1, -1, 1)
            # ∂w_c/∂x_d = ±(res/2) Π_{e≠d} factor_e, as products of slices (no gathers)
            ones = torch.ones_like(factors[..., :1])
            before = torch.cat([ones, factors[..., :-1]], -1).cumprod(-1)       # Π_{e<d}
            after = torch.cat([factors[..., 1:], ones], -1).flip(-1).cumprod(-1).flip(-1)  # Π_{e>d}
            slopes = (before * after) * (on.to(x.dtype) * 2.0 - 1.0) * half_res.unsqueeze(-1)
            weights = before[..., -1] * factors[..., -1]                        # (N, L, C)
            blend = torch.cat([weights.unsqueeze(-1), slopes], -1)              # (N, L, C, 1 + dim)
        values = self._corner_values(index)                                     # (N, L, C, F)
        # Σ_c over the corners as one broadcast product and sum: einsum would make thousands of tiny bmm's
        both = (blend.unsqueeze(-2) * values.unsqueeze(-1)).sum(2)              # (N, L, F, 1 + dim)
        n = x.shape[0]
        return both[..., 0].reshape(n, -1), both[..., 1:].reshape(n, -1, self.dim)
