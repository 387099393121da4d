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
from torch.autograd.function import once_differentiable

from deepcurrents.errors import ConfigError, positive_int

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
            positive_int(f"model.grid_encoding.{name}", value)
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
        gen = torch.Generator().manual_seed(seed) if seed is not None else None
        table = (torch.rand(sum(sizes), features, generator=gen) * 2.0 - 1.0) * init_scale
        self.table = nn.Parameter(table)

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs):
        # checkpoints written before the corner order became implicit in _cells carry a "corners" buffer
        state_dict.pop(prefix + "corners", None)
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    @property
    def out_dim(self) -> int:
        return self.levels * self.features

    def _cells(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Per level, the table rows of the 2^dim corners of x's cell, (C, L, N), corner (c_0, …, c_{dim-1}) in
        {0, 1}^dim at row Σ_d c_d 2^(dim-1-d), and x's position in its cell, (dim, L, N), still differentiable in x.

        Laid out corner- and level-major (points innermost) so that every product and sum below runs over
        contiguous rows of N points: the (N, L, C, ·) layout made PyTorch's CPU kernels broadcast over tiny
        trailing dimensions, 4-5x slower.
        """
        res = self.resolutions.view(1, -1, 1)                                  # (1, L, 1)
        u = (x.clamp(-1.0, 1.0).T.unsqueeze(1) + 1.0) * (0.5 * res.to(x.dtype))  # (dim, L, N)
        cell = torch.minimum(u.detach().floor().long(), res - 1)              # (dim, L, N)
        shape = (2,) * self.dim + cell.shape[1:]
        dense = torch.zeros((), dtype=torch.long, device=x.device)
        hashed = torch.zeros((), dtype=torch.long, device=x.device)
        stride = torch.ones_like(res)
        for d in range(self.dim):  # axis d of the (2,)*dim corner block is c_d: c_{dim-1} varies fastest
            view = [1] * self.dim + [1, 1]
            view[d] = 2
            step = torch.arange(2, device=x.device).view(view)
            vertex_d = cell[d] + step                                          # (…2 at axis d…, L, N)
            dense = dense + vertex_d * stride                                  # x fastest: i + (r+1)(j + (r+1)k)
            hashed = hashed ^ (vertex_d * _PRIMES[d])
            stride = stride * (res + 1)
        dense, hashed = dense.expand(shape), hashed.expand(shape)
        index = torch.where(self.hashed.view(-1, 1), hashed % self.sizes.view(-1, 1), dense)
        index = index + self.offsets[:-1].view(-1, 1)
        return index.reshape(-1, *cell.shape[1:]), u - cell.to(x.dtype)

    def _factors(self, t: torch.Tensor, slopes: bool) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Multilinear weights w_c = Π_d (t_d or 1 − t_d), (C, L, N), as an outer product over the dims, and,
        with ``slopes``, their x-derivatives ∂w_c/∂x_d = ±(res/2) Π_{e≠d} (…), (dim, C, L, N) (else None)."""
        pairs = [torch.stack([1.0 - t[d], t[d]]) for d in range(self.dim)]   # each (2, L, N)

        def outer(factors: list[torch.Tensor]) -> torch.Tensor:
            out = factors[0]
            for f in factors[1:]:
                out = out.unsqueeze(1) * f.unsqueeze(0)
                out = out.reshape(-1, *f.shape[1:])
            return out                                                          # (2^dim, L, N)

        weights = outer(pairs)
        if not slopes:
            return weights, None
        half_res = (0.5 * self.resolutions.to(t.dtype)).view(-1, 1)
        sign = torch.tensor([-1.0, 1.0], dtype=t.dtype, device=t.device).view(2, 1, 1)
        slopes = torch.stack([outer([*pairs[:d], (sign * half_res).expand_as(pairs[d]), *pairs[d + 1:]])
                              for d in range(self.dim)])
        return weights, slopes

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Features (N, L·F), differentiable in x and in the table."""
        index, t = self._cells(x)
        weights, _ = self._factors(t, slopes=False)
        values = self.table.index_select(0, index.reshape(-1)).T.reshape(self.features, *index.shape)
        out = (weights.unsqueeze(0) * values).sum(1)                            # (F, L, N)
        return out.permute(2, 1, 0).reshape(x.shape[0], -1)

    def features_and_jacobian(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The features (N, L·F) and their Jacobian ∂features/∂x (N, L·F, dim) in closed form, both linear in the
        table: the training step differentiates them once (in the table), not twice through the weights."""
        with torch.no_grad():
            index, t = self._cells(x)
            weights, slopes = self._factors(t, slopes=True)
            blend = torch.cat([weights.unsqueeze(0), slopes])                   # (1 + dim, C, L, N)
        both = _Blend.apply(self.table, index, blend)                           # (1 + dim, F, L, N)
        n = x.shape[0]
        return (both[0].permute(2, 1, 0).reshape(n, -1),
                both[1:].permute(3, 2, 1, 0).reshape(n, -1, self.dim))


class _Blend(torch.autograd.Function):
    """out[k, f, l, n] = Σ_c blend[k, c, l, n] · table[index[c, l, n], f]: linear in the table, so its backward is
    one product, a sum over k and one ``index_add`` (autograd's gather/broadcast/sum chain did the same work on
    (N, L, C, F, 1 + dim) arrays)."""

    @staticmethod
    def forward(ctx, table: torch.Tensor, index: torch.Tensor, blend: torch.Tensor) -> torch.Tensor:
        features = table.shape[1]
        values = table.index_select(0, index.reshape(-1)).T.reshape(features, 1, *index.shape)  # (F, 1, C, L, N)
        ctx.save_for_backward(index, blend)
        ctx.table_shape = table.shape
        return (blend.unsqueeze(1) * values.transpose(0, 1)).sum(2)            # (1 + dim, F, L, N)

    @staticmethod
    @once_differentiable
    def backward(ctx, out_bar: torch.Tensor):
        index, blend = ctx.saved_tensors
        # values_bar[f, c, l, n] = Σ_k blend[k, c, l, n] · out_bar[k, f, l, n]
        values_bar = (blend.unsqueeze(1) * out_bar.unsqueeze(2)).sum(0)         # (F, C, L, N)
        table_bar = out_bar.new_zeros(ctx.table_shape)
        table_bar.index_add_(0, index.reshape(-1), values_bar.reshape(values_bar.shape[0], -1).T)
        return table_bar, None, None
