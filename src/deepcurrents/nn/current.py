"""The neural current ω = ∇f_θ + alpha_scale · α_Γ (paper eq. alpha-hodge)."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from deepcurrents.errors import ConfigError
from deepcurrents.geometry import biot_savart, biot_savart_2d
from deepcurrents.nn.field_gradient import check_matmul_precision, closed_form_supported, field_and_gradient
from deepcurrents.nn.fourier import FourierFeatures
from deepcurrents.nn.grid_encoding import MultiresGrid
from deepcurrents.nn.mlp import FieldMLP


def spatial_gradient(f: torch.Tensor, x: torch.Tensor, create_graph: bool) -> torch.Tensor:
    """∂f/∂x by autograd, per sample. f: (N,) computed row-wise from x: (N, D) with requires_grad → (N, D)."""
    (grad,) = torch.autograd.grad(f.sum(), x, create_graph=create_graph)
    return grad


class NeuralCurrent(nn.Module):
    """A single current ω = ∇f_θ + alpha_scale·α_Γ on [-1, 1]^d with a fixed boundary Γ.

    3D: ``loops`` is a list of (M_i, 3) closed loops. 2D: ``poles`` (P, 2) with ``signs`` (P,).
    The boundary is kept as buffers, so it travels with the module's device and its state_dict.
    ``zero_init_output`` zeroes the last layer's weights (f ≡ const at the start; the authors' code uses
    PyTorch's default initialisation, ``zero_init_output=False``).
    ``gradient``: how ``forward`` gets ∇f: "closed_form" (``nn.field_gradient``: one pass with a hand-written
    backward, the default) or "autograd" (autograd through the MLP, the reference); the same numbers.
    ``grid``: keyword arguments of ``MultiresGrid`` (levels, base_resolution, finest_resolution, features,
    table_size, init_scale) for learned grid features beside the Fourier features (not in the paper); None: off.
    ``coarse_to_fine``, ``coarse_start``: the Fourier frequencies open during training (``FourierFeatures``).
    ``matmul_precision``: "highest" (IEEE fp32 products) or "medium" (bf16 / TF32 internals in the training
    pass's products where the hardware has them; ``nn.field_gradient``); evaluation is fp32 either way.
    """

    gradient: str = "closed_form"

    def __init__(
        self,
        dim: int = 3,
        loops: Sequence[torch.Tensor] | None = None,
        poles: torch.Tensor | None = None,
        signs: torch.Tensor | None = None,
        num_frequencies: int = 1024,
        sigma: float = 2.0,
        rff: bool = True,
        width: int = 256,
        depth: int = 4,
        activation: str = "softplus",
        alpha_scale: float = 1e-3,
        rff_seed: int | None = None,
        zero_init_output: bool = True,
        grid: dict | None = None,
        coarse_to_fine: float = 0.0,
        coarse_start: float = 0.25,
        matmul_precision: str = "highest",
    ):
        super().__init__()
        if dim not in (2, 3):
            raise ConfigError(f"model.dim={dim} must be 2 or 3.")
        self.dim = dim
        self.alpha_scale = alpha_scale
        self.matmul_precision = check_matmul_precision(matmul_precision)
        self.encoding = FourierFeatures(dim, num_frequencies, sigma, enabled=rff, seed=rff_seed,
                                        coarse_to_fine=coarse_to_fine, coarse_start=coarse_start)
        self.grid = MultiresGrid(dim, seed=rff_seed, **grid) if grid else None
        self.mlp = FieldMLP(self.encoding.out_dim + (self.grid.out_dim if self.grid else 0), width, depth, activation)
        if zero_init_output:
            # f starts constant, so ω starts as alpha_scale·α (mass ≈ 2.4 for a circle of radius 0.6)
            # instead of as the random network's gradient, which is 15–40× larger than α: measured here,
            # the mass bound after 1000 CPU steps was 1.56 with and 1.97 without (disk area 1.13)
            nn.init.zeros_(self.mlp.net[-1].weight)
        if dim == 3:
            if not loops:
                raise ConfigError("A 3D current needs at least one boundary loop.")
            self.register_buffer("vertices", torch.cat([torch.as_tensor(lp) for lp in loops]).float())
            self.register_buffer("loop_sizes", torch.tensor([len(lp) for lp in loops], dtype=torch.long))
        else:
            if poles is None or signs is None:
                raise ConfigError("A 2D current needs boundary points and their signs.")
            self.register_buffer("poles", torch.as_tensor(poles).float())
            self.register_buffer("signs", torch.as_tensor(signs).float())

    @property
    def loops(self) -> list[torch.Tensor]:
        """The boundary loops, list of (M_i, 3) (3D only)."""
        return list(torch.split(self.vertices, self.loop_sizes.tolist()))

    def f(self, x: torch.Tensor) -> torch.Tensor:
        """The scalar field f_θ. (N, d) → (N,)."""
        features = self.encoding(x)
        if self.grid is not None:
            features = torch.cat([features, self.grid(x)], dim=-1)
        return self.mlp(features).squeeze(-1)

    def alpha(self, x: torch.Tensor) -> torch.Tensor:
        """alpha_scale · α_Γ(x), closed form. (N, d) → (N, d)."""
        if self.dim == 3:
            field = biot_savart(x, self.loops)
        else:
            field = biot_savart_2d(x, self.poles, self.signs)
        return self.alpha_scale * field

    def forward(self, x: torch.Tensor, create_graph: bool = True,
                alpha: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """(f, ω) at points x: (N, d) → ((N,), (N, d)). ``create_graph`` for training (double backward).
        ``alpha`` (N, d): the unscaled α_Γ(x) if already known (a sample pool), else computed here.

        ∇f and its training backward are written out by hand (``nn.field_gradient``); with
        ``gradient="autograd"``, ∇f is taken by autograd through the MLP to its input features, then through the
        Fourier features by their closed-form Jacobian. Same numbers either way (tests/test_nn.py).
        """
        x = x.detach()
        # the hand-written pass: the MLP on the Fourier features and, if any, the grid features after them
        extra_dim = self.grid.out_dim if self.grid is not None else 0
        if self.gradient == "closed_form" and closed_form_supported(self.mlp, self.encoding, extra_dim=extra_dim):
            with torch.set_grad_enabled(create_graph and torch.is_grad_enabled()):
                f, grad_f = field_and_gradient(self.mlp, self.encoding, x, grid=self.grid,
                                               matmul_precision=self.matmul_precision)
            return f, grad_f + (self.alpha(x) if alpha is None else self.alpha_scale * alpha)
        with torch.enable_grad():
            # autograd to the MLP's input features, then each encoding's closed-form Jacobian (Fourier: 2πB cos/sin;
            # grid: its multilinear weights' slopes); x itself only when the Fourier features are off
            parts, wrt = [], []
            if self.encoding.enabled:
                sin, cos = self.encoding.sin_cos(x)
                parts.append(torch.cat([sin, cos], dim=-1).requires_grad_(True))
            else:
                parts.append(x.requires_grad_(True))
            wrt.append(parts[-1])
            if self.grid is not None:
                grid_features, grid_jacobian = self.grid.features_and_jacobian(x)
                parts.append(grid_features)
                wrt.append(grid_features)
            f = self.mlp(torch.cat(parts, dim=-1) if len(parts) > 1 else parts[0]).squeeze(-1)
            grads = torch.autograd.grad(f.sum(), wrt, create_graph=create_graph)
            grad_f = self.encoding.input_gradient(grads[0], sin, cos) if self.encoding.enabled else grads[0]
            if self.grid is not None:
                grad_f = grad_f + torch.einsum("nk,nkd->nd", grads[1], grid_jacobian)
        if not create_graph:
            f, grad_f = f.detach(), grad_f.detach()
        return f, grad_f + (self.alpha(x) if alpha is None else self.alpha_scale * alpha)

    @torch.no_grad()
    def evaluate(self, x: torch.Tensor, chunk_size: int = 1 << 15, omega: bool = True):
        """f (and ω) at many points in chunks, without keeping graphs. (N, d) → (N,) [, (N, d)]."""
        fs, ws = [], []
        for chunk in torch.split(x, chunk_size):
            if omega:
                f, w = self(chunk, create_graph=False)
                ws.append(w)
            else:
                f = self.f(chunk)
            fs.append(f)
        return (torch.cat(fs), torch.cat(ws)) if omega else torch.cat(fs)
