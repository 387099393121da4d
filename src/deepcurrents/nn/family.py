"""Families of currents: the boundary-conditioned autodecoder (paper §4.3, Fig. 5 bottom).

f_θ(x; z, Γ) = h_θ([z | E_1(Γ_1) | … | E_B(Γ_B) | RFF(x)]) and ω = ∇_x f_θ + alpha_scale·α_Γ, where z is
the shape's latent code, E_b the encoder of boundary loop b and α_Γ the Biot–Savart field of the shape's
own (augmented) boundary.

Shapes are batched as S shapes × N points. Loops are padded: ``loops`` (S, B, L, 3) with ``mask``
(S, B, L) marking each loop's real vertices (first), so loops of different lengths share a batch.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import nn

from deepcurrents.errors import positive_int
from deepcurrents.geometry import biot_savart
from deepcurrents.nn.current import NeuralCurrent, spatial_gradient
from deepcurrents.nn.encoder import BoundaryEncoder
from deepcurrents.nn.extensions.window import FieldWindow
from deepcurrents.nn.field_gradient import check_matmul_precision, closed_form_supported, field_and_gradient
from deepcurrents.nn.fourier import FourierFeatures
from deepcurrents.nn.mlp import FieldMLP


def pad_loops(shapes: Sequence[Sequence[torch.Tensor]]) -> tuple[torch.Tensor, torch.Tensor]:
    """Pads S shapes × B loops of (M_sb, 3) vertices. → loops (S, B, L, 3) (zeros after the real
    vertices), mask (S, B, L) bool, L = max M_sb."""
    s, b = len(shapes), len(shapes[0])
    length = max(len(lp) for shape in shapes for lp in shape)
    ref = shapes[0][0]
    loops = torch.zeros(s, b, length, 3, dtype=ref.dtype, device=ref.device)
    mask = torch.zeros(s, b, length, dtype=torch.bool, device=ref.device)
    for i, shape in enumerate(shapes):
        for j, lp in enumerate(shape):
            loops[i, j, : len(lp)] = lp
            mask[i, j, : len(lp)] = True
    return loops, mask


def unpad_loops(loops: torch.Tensor, mask: torch.Tensor) -> list[list[torch.Tensor]]:
    """The inverse of ``pad_loops``: (S, B, L, 3), (S, B, L) → S lists of B tensors (M_sb, 3)."""
    counts = mask.sum(-1).tolist()
    return [[loops[i, j, : counts[i][j]] for j in range(loops.shape[1])] for i in range(loops.shape[0])]


class FamilyCurrent(nn.Module):
    """Latent codes (one per training shape, N(0, latent_std²)), one boundary encoder per loop, and the
    decoder h_θ (Fourier features + field MLP, as for a single current).

    Args:
        num_shapes: training shapes (rows of the latent embedding).
        num_loops: boundary loops B per shape (the same for the whole family).
        latent_dim, boundary_dim: sizes of z and of each z_Γb (paper: 256, 256).
        num_frequencies, sigma, rff, width, depth, activation, alpha_scale, rff_seed, coarse_to_fine,
            coarse_start, matmul_precision: as ``NeuralCurrent``.
        latent_std: standard deviation of the initial codes (paper: 0.1).
        zero_init_output: zero the decoder's last layer (f ≡ const at the start; False: PyTorch's default).
        f_turns: > 0 (beyond the paper) confines f to a window of ``f_turns`` full jumps, f = W·tanh(h)
            (``nn.extensions.window``); 0: unbounded (the paper).
    """

    def __init__(
        self,
        num_shapes: int,
        num_loops: int,
        latent_dim: int = 256,
        boundary_dim: int = 256,
        num_frequencies: int = 1024,
        sigma: float = 2.0,
        rff: bool = True,
        width: int = 256,
        depth: int = 4,
        activation: str = "softplus",
        alpha_scale: float = 1e-3,
        rff_seed: int | None = None,
        latent_std: float = 0.1,
        zero_init_output: bool = True,
        coarse_to_fine: float = 0.0,
        coarse_start: float = 0.25,
        matmul_precision: str = "highest",
        f_turns: float = 0.0,
    ):
        super().__init__()
        for key, value in (("num_shapes", num_shapes), ("num_loops", num_loops), ("latent_dim", latent_dim),
                           ("boundary_dim", boundary_dim)):
            positive_int(f"model.{key}", value)
        self.num_loops = int(num_loops)
        self.alpha_scale = float(alpha_scale)  # the settings are checked by experiments.schema
        self.window = FieldWindow(f_turns, self.alpha_scale)  # f = W·tanh(h) (nn.extensions.window; 0: off)
        self.matmul_precision = check_matmul_precision(matmul_precision)
        self.latents = nn.Embedding(int(num_shapes), int(latent_dim))
        nn.init.normal_(self.latents.weight, mean=0.0, std=float(latent_std))
        self.encoders = nn.ModuleList(BoundaryEncoder(int(boundary_dim)) for _ in range(self.num_loops))
        self.encoding = FourierFeatures(3, num_frequencies, sigma, enabled=rff, seed=rff_seed,
                                        coarse_to_fine=coarse_to_fine, coarse_start=coarse_start)
        self.code_dim = int(latent_dim) + self.num_loops * int(boundary_dim)
        self.mlp = FieldMLP(self.code_dim + self.encoding.out_dim, width, depth, activation)
        if zero_init_output:  # f starts constant (ω = α) for every code, as NeuralCurrent does
            nn.init.zeros_(self.mlp.net[-1].weight)
            if self.f_turns:  # and f ≡ 0, the window's middle: PyTorch's bias (±1/√width) would start it saturated
                nn.init.zeros_(self.mlp.net[-1].bias)

    @property
    def num_shapes(self) -> int:
        return self.latents.num_embeddings

    def code(self, z: torch.Tensor, loops: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        """[z | z_Γ1 | … | z_ΓB]. z (S, latent_dim), loops (S, B, L, 3), mask (S, B, L) → (S, code_dim)."""
        if loops.shape[1] != self.num_loops:
            raise ValueError(f"expected {self.num_loops} boundary loops per shape, got {loops.shape[1]}")
        parts = [z] + [enc(loops[:, b], None if mask is None else mask[:, b]) for b, enc in enumerate(self.encoders)]
        return torch.cat(parts, dim=-1)

    def decode(self, features: torch.Tensor, code: torch.Tensor) -> torch.Tensor:
        """h_θ([code | features]). features (S, N, F), code (S, code_dim) → (S, N).

        The first layer is split into its code and feature columns so the code's part is computed once
        per shape instead of materialising S·N copies of the code (the same numbers as concatenating).
        """
        first = self.mlp.net[0]
        c = self.code_dim
        h = F.linear(features, first.weight[:, c:]) + F.linear(code, first.weight[:, :c], first.bias)[:, None]
        return self.window(self.mlp.net[1:](h).squeeze(-1))

    @property
    def f_turns(self) -> float:
        """The window's width in full jumps (``nn.extensions.window``; 0: no window)."""
        return self.window.turns

    @f_turns.setter
    def f_turns(self, turns: float) -> None:
        self.window = FieldWindow(turns, self.alpha_scale)

    @property
    def half_window(self) -> float:
        """W = f_turns·J/2, J = 4π·alpha_scale (0: no window)."""
        return self.window.half_width

    def f(self, x: torch.Tensor, code: torch.Tensor) -> torch.Tensor:
        """f_θ(x; code). x (S, N, 3), code (S, code_dim) → (S, N)."""
        return self.decode(self.encoding(x), code)

    def alpha(self, x: torch.Tensor, loops: Sequence[Sequence[torch.Tensor]]) -> torch.Tensor:
        """alpha_scale·α of each shape's own loops. x (S, N, 3), loops: S lists of (M, 3) → (S, N, 3)."""
        return self.alpha_scale * torch.stack([biot_savart(xs, shape) for xs, shape in zip(x, loops, strict=True)])

    def forward(self, x: torch.Tensor, code: torch.Tensor, loops: torch.Tensor, mask: torch.Tensor,
                create_graph: bool = True) -> tuple[torch.Tensor, torch.Tensor]:
        """(f, ω) at x (S, N, 3) for codes (S, code_dim) and padded loops → ((S, N), (S, N, 3))."""
        x = x.detach()
        if closed_form_supported(self.mlp, self.encoding, self.code_dim):  # nn.field_gradient: the same numbers
            with torch.set_grad_enabled(create_graph and torch.is_grad_enabled()):
                first, c = self.mlp.net[0], self.code_dim
                bias = F.linear(code, first.weight[:, :c], first.bias)  # the code's part, once per shape (decode)
                f, grad_f = self.window(*field_and_gradient(self.mlp, self.encoding, x,
                                                            first_layer=(first.weight[:, c:], bias),
                                                            matmul_precision=self.matmul_precision))
            with torch.no_grad():
                alpha = self.alpha(x, unpad_loops(loops, mask))
            return f, grad_f + alpha
        with torch.enable_grad():
            if self.encoding.enabled:  # ∇f through the Fourier features by their closed-form Jacobian
                sin, cos = self.encoding.sin_cos(x)
                features = torch.cat([sin, cos], dim=-1).requires_grad_(True)
                f = self.decode(features, code)
                grad_f = self.encoding.input_gradient(spatial_gradient(f, features, create_graph), sin, cos)
            else:
                x_in = x.requires_grad_(True)
                f = self.decode(x_in, code)
                grad_f = spatial_gradient(f, x_in, create_graph=create_graph)
        if not create_graph:
            f, grad_f = f.detach(), grad_f.detach()
        with torch.no_grad():  # α depends on data only; no graph needed
            alpha = self.alpha(x, unpad_loops(loops, mask))
        return f, grad_f + alpha


class ConditionedCurrent(nn.Module):
    """One member of a family as a single current: a FamilyCurrent with a fixed latent code z and
    boundary Γ. Has the interface meshing and metrics expect of a ``NeuralCurrent`` (``dim``, ``loops``,
    ``f``, ``alpha``, ``forward``, ``evaluate``).

    Args:
        family: the trained FamilyCurrent (shared, not copied).
        z: (latent_dim,) the latent code.
        loops: B loops (M_b, 3), matched to the family's loop order.
    """

    dim = 3

    def __init__(self, family: FamilyCurrent, z: torch.Tensor, loops: Sequence[torch.Tensor]):
        super().__init__()
        self.family = family
        self.alpha_scale = family.alpha_scale
        device = next(family.parameters()).device
        loops = [torch.as_tensor(lp, dtype=torch.float32, device=device) for lp in loops]
        self.register_buffer("vertices", torch.cat(loops))
        self.register_buffer("loop_sizes", torch.tensor([len(lp) for lp in loops], dtype=torch.long))
        self._loop_sizes = [len(lp) for lp in loops]  # what NeuralCurrent.loops splits by (no device read)
        padded, mask = pad_loops([loops])
        with torch.no_grad():
            code = family.code(torch.as_tensor(z, dtype=torch.float32, device=device)[None], padded, mask)[0]
        self.register_buffer("code", code)

    # the same list-of-loops view and chunked evaluation as a single current (they only use f and forward)
    loops = NeuralCurrent.loops
    evaluate = NeuralCurrent.evaluate

    def forward(self, x: torch.Tensor, create_graph: bool = True) -> tuple[torch.Tensor, torch.Tensor]:
        """(f, ω) at x (N, 3) → ((N,), (N, 3))."""
        padded, mask = pad_loops([self.loops])
        f, omega = self.family(x[None], self.code[None], padded, mask, create_graph=create_graph)
        return f[0], omega[0]

    def f(self, x: torch.Tensor) -> torch.Tensor:
        """(N, 3) → (N,)."""
        return self.family.f(x[None], self.code[None])[0]

    def alpha(self, x: torch.Tensor) -> torch.Tensor:
        """alpha_scale·α_Γ(x). (N, 3) → (N, 3)."""
        return self.alpha_scale * biot_savart(x, self.loops)
