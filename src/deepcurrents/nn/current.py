"""The neural current ω = ∇f_θ + a·α_Γ (paper §4, eq. alpha-hodge), on [-1, 1]^d with a fixed boundary Γ."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from deepcurrents.geometry import angle_2d, biot_savart, biot_savart_2d
from deepcurrents.geometry.biot_savart import segment_table, solid_angle
from deepcurrents.nn.extensions import ExtensionHost
from deepcurrents.nn.field_gradient import network_and_gradient
from deepcurrents.nn.fourier import FourierFeatures
from deepcurrents.nn.mlp import FieldMLP


def spatial_gradient(f: torch.Tensor, x: torch.Tensor, create_graph: bool) -> torch.Tensor:
    """∂f/∂x by autograd, per sample. f: (N,) computed row-wise from x: (N, D) with requires_grad → (N, D)."""
    (grad,) = torch.autograd.grad(f.sum(), x, create_graph=create_graph)
    return grad


def _read_state_after_loading(module: NeuralCurrent, incompatible_keys) -> None:
    """``load_state_dict``'s post-hook: the buffers may have changed (``NeuralCurrent._read_state``)."""
    module._read_state()


class NeuralCurrent(ExtensionHost, nn.Module):
    """ω = ∇f_θ + a·α_Γ: f_θ = MLP(φ(x)), φ the random Fourier features [sin 2πBx, cos 2πBx] (paper §4.3), then
    ``grid`` features if given (``nn.MultiresGrid``, beyond the paper); α_Γ the Biot–Savart field of Γ in closed
    form; a = ``alpha_scale`` (paper: 1e-3). Γ: ``loops``, a list of (M_i, 3) closed loops (3D), or ``poles``
    (P, 2) with ``signs`` (P,) (2D), kept as buffers. ∇f_θ comes from the hand-written pass of
    ``nn.field_gradient`` (``gradient="autograd"``: autograd, the reference; the same numbers).
    ``extensions`` (``nn.extensions``, beyond the paper) may give f an output basis in the boundary's angle u
    (phase harmonics) or transform (f, ω) afterwards (phase sharpening); none: the paper's current."""

    gradient: str = "closed_form"

    def __init__(self, encoding: FourierFeatures, mlp: FieldMLP, loops: Sequence[torch.Tensor] | None = None,
                 poles: torch.Tensor | None = None, signs: torch.Tensor | None = None, grid: nn.Module | None = None,
                 alpha_scale: float = 1e-3, matmul_precision: str = "highest", extensions: Sequence = ()):
        super().__init__()
        self.dim, self.alpha_scale, self.matmul_precision = encoding.in_dim, alpha_scale, matmul_precision
        self.encoding, self.grid, self.mlp = encoding, grid, mlp
        if self.dim == 3:
            self.register_buffer("vertices", torch.cat([torch.as_tensor(lp) for lp in loops]).float())
            self.register_buffer("loop_sizes", torch.tensor([len(lp) for lp in loops], dtype=torch.long))
        else:
            self.register_buffer("poles", torch.as_tensor(poles).float())
            self.register_buffer("signs", torch.as_tensor(signs).float())
        self.attach_extensions(extensions)
        self._read_state()
        self.register_load_state_dict_post_hook(_read_state_after_loading)

    def _read_state(self) -> None:
        """Python copies of the buffers the forward reads, made after each load (a GPU step would wait for every
        read); forgets α's segment tables, which follow the loops."""
        self._loop_sizes = self.loop_sizes.tolist() if self.dim == 3 else []
        self._segments = {}  # (dtype, device) → the loops' biot_savart.segment_table, made on first use
        self.read_extensions()

    @property
    def loops(self) -> list[torch.Tensor]:
        """The boundary loops, list of (M_i, 3) (3D only)."""
        return list(torch.split(self.vertices, self._loop_sizes))

    def field(self, x: torch.Tensor) -> torch.Tensor:
        """α_Γ(x) unscaled, closed form (``geometry.biot_savart``). (N, d) → (N, d)."""
        if self.dim == 3:
            key = (x.dtype, x.device)
            if key not in self._segments:  # Γ is fixed: its segments once, not in every step
                self._segments[key] = segment_table(self.loops, x.dtype, x.device)
            return biot_savart(x, segments=self._segments[key])
        return biot_savart_2d(x, self.poles, self.signs)

    def alpha(self, x: torch.Tensor) -> torch.Tensor:
        """a · α_Γ(x), closed form. (N, d) → (N, d)."""
        return self.alpha_scale * self.field(x)

    def boundary_angle(self, x: torch.Tensor) -> torch.Tensor | None:
        """u, Γ's part of the phase, where an extension needs it now (else None): Ω_Γ(x)/2 in 3D (∇u = α/2),
        Σ_j s_j·angle(x − p_j) in 2D (∇u = α). (N, d) → (N,), no gradient."""
        if not self.needs_angle:
            return None
        with torch.no_grad():
            x = x.detach()
            return 0.5 * solid_angle(x, self.loops) if self.dim == 3 else angle_2d(x, self.poles, self.signs)

    def network_f(self, x: torch.Tensor, u: torch.Tensor | None) -> torch.Tensor:
        """f_θ, the network's f before any transform; u from ``boundary_angle``. (N, d) → (N,)."""
        features = self.encoding(x)
        if self.grid is not None:
            features = torch.cat([features, self.grid(x)], dim=-1)
        basis = self.output_basis(x, u)
        return self.mlp(features).squeeze(-1) if basis is None else (self.mlp(features) * basis[0]).sum(-1)

    def f(self, x: torch.Tensor) -> torch.Tensor:
        """The scalar field f (through the extensions). (N, d) → (N,)."""
        u = self.boundary_angle(x)
        f = self.network_f(x, u)
        for extension in self.extensions:
            f = extension.transform(self, f, None, u)[0]
        return f

    def forward(self, x: torch.Tensor, create_graph: bool = True,
                alpha: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """(f, ω) at points x: (N, d) → ((N,), (N, d)). ``create_graph`` for training (double backward);
        ``alpha`` (N, d): the unscaled α_Γ(x) if already known (a sample pool), else computed here."""
        x = x.detach()
        field = self.field(x) if alpha is None else alpha
        u = self.boundary_angle(x)
        basis = self.output_basis(x, u)
        with torch.set_grad_enabled(create_graph and torch.is_grad_enabled()):
            h, grad_h = network_and_gradient(self.mlp, self.encoding, x, self.grid, None if basis is None else basis[0],
                                             create_graph, self.gradient, self.matmul_precision)
            f, omega = self._current(h, grad_h, basis, field)
            for extension in self.extensions:
                f, omega = extension.transform(self, f, omega, u)
        return f, omega

    def _current(self, h: torch.Tensor, grad_h: torch.Tensor, basis: tuple | None,
                 field: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(f, ω = ∇f + a·α) from the network's outputs h and their gradient; with an output basis (e, ∂e/∂u),
        ∇f gains (h·∂e/∂u)·∇u, which joins α (∇u = α/2): ω = Σ_m e_m ∇h_m + (a + (h·∂e/∂u)/2)·α."""
        if basis is None:
            return h, grad_h + self.alpha_scale * field
        e, slope = basis
        return (h * e).sum(-1), grad_h + (self.alpha_scale + 0.5 * (h * slope).sum(-1, keepdim=True)) * field

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
