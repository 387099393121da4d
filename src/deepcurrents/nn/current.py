"""The neural current ω = ∇f_θ + alpha_scale · α_Γ (paper eq. alpha-hodge)."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from deepcurrents.errors import ConfigError
from deepcurrents.geometry import biot_savart, biot_savart_2d
from deepcurrents.nn.field_gradient import closed_form_supported, field_and_gradient
from deepcurrents.nn.fourier import FourierFeatures
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
    ):
        super().__init__()
        if dim not in (2, 3):
            raise ConfigError(f"model.dim={dim} must be 2 or 3.")
        self.dim = dim
        self.alpha_scale = alpha_scale
        self.encoding = FourierFeatures(dim, num_frequencies, sigma, enabled=rff, seed=rff_seed)
        self.mlp = FieldMLP(self.encoding.out_dim, width, depth, activation)
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
        return self.mlp(self.encoding(x)).squeeze(-1)

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
        if self.gradient == "closed_form" and closed_form_supported(self.mlp, self.encoding):
            with torch.set_grad_enabled(create_graph and torch.is_grad_enabled()):
                f, grad_f = field_and_gradient(self.mlp, self.encoding, x)
            return f, grad_f + (self.alpha(x) if alpha is None else self.alpha_scale * alpha)
        with torch.enable_grad():
            if self.encoding.enabled:
                sin, cos = self.encoding.sin_cos(x)
                features = torch.cat([sin, cos], dim=-1).requires_grad_(True)
                f = self.mlp(features).squeeze(-1)
                grad_features = spatial_gradient(f, features, create_graph=create_graph)
                grad_f = self.encoding.input_gradient(grad_features, sin, cos)
            else:
                x_in = x.requires_grad_(True)
                f = self.mlp(x_in).squeeze(-1)
                grad_f = spatial_gradient(f, x_in, create_graph=create_graph)
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
