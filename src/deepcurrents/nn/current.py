"""The neural current ω = ∇f_θ + alpha_scale · α_Γ (paper eq. alpha-hodge)."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from deepcurrents.errors import ConfigError
from deepcurrents.geometry import biot_savart, biot_savart_2d
from deepcurrents.geometry.biot_savart import solid_angle
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
    ``phase_harmonics`` K > 0 (3D, beyond the paper): f = h_0(x) + alpha_scale·Σ_k [h_k(x) cos ku + h'_k(x) sin ku]/k
    with u = Ω_Γ(x)/2 and (h_0, h_k, h'_k) the MLP's 2K + 1 outputs (``phase_basis``). The minimal current's f is
    −alpha_scale·Ω with Ω's branch cut on the surface: a sawtooth in u, whose jump the Fourier-feature MLP can only
    smear, and whose fan of level sets around Γ (every level meets Γ) it cannot fold at all. The harmonics of u
    are smooth off Γ (u is defined modulo 2π) and wind around Γ at every scale, so the truncated sawtooth
    Σ_k (−1)^k 2·sin(k(u − c))/k is in reach of constant outputs, and a jump across any surface spanning Γ (the
    level set u = c(x) + π for a smooth c) in reach of smooth ones. K = 0 is the paper's network.
    ``phase_harmonics_start``: the fraction of the training budget before the harmonics open (linearly over the
    next ``HARMONICS_RAMP`` of it, ``set_progress``); until then f = h_0 alone. From the start, the harmonics
    settle the jump on the solid angle's nearest level set, which for a knotted curve is far from minimal (the
    trefoil's: 0.83 against 0.737) and stays there; opened later, they sharpen the jump where h_0 has put it.
    """

    HARMONICS_RAMP = 0.2

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
        phase_harmonics: int = 0,
        phase_harmonics_start: float = 0.0,
    ):
        super().__init__()
        if dim not in (2, 3):
            raise ConfigError(f"model.dim={dim} must be 2 or 3.")
        if isinstance(phase_harmonics, bool) or not isinstance(phase_harmonics, int) or phase_harmonics < 0:
            raise ConfigError(f"model.net.phase_harmonics={phase_harmonics!r} must be a whole number ≥ 0 "
                              "(0: the paper's scalar network).")
        if phase_harmonics and dim != 3:
            raise ConfigError(f"model.net.phase_harmonics={phase_harmonics} needs a 3D boundary (the harmonics are "
                              "those of the solid angle); use 0 for 2D curves.")
        if not 0.0 <= float(phase_harmonics_start) < 1.0:
            raise ConfigError(f"model.net.phase_harmonics_start={phase_harmonics_start} must be a fraction of the "
                              "training budget in [0, 1).")
        self.phase_harmonics = phase_harmonics
        self.phase_harmonics_start = float(phase_harmonics_start)
        # the harmonics' weight in f: 1 unless they open later (a buffer, so a checkpoint evaluates as trained;
        # none without harmonics, so the paper network's checkpoints keep their keys)
        if phase_harmonics:
            self.register_buffer("harmonic_gate", torch.tensor(0.0 if self.phase_harmonics_start > 0 else 1.0))
        self.dim = dim
        self.alpha_scale = alpha_scale
        self.matmul_precision = check_matmul_precision(matmul_precision)
        self.encoding = FourierFeatures(dim, num_frequencies, sigma, enabled=rff, seed=rff_seed,
                                        coarse_to_fine=coarse_to_fine, coarse_start=coarse_start)
        self.grid = MultiresGrid(dim, seed=rff_seed, **grid) if grid else None
        self.mlp = FieldMLP(self.encoding.out_dim + (self.grid.out_dim if self.grid else 0), width, depth, activation,
                            out_dim=1 + 2 * phase_harmonics)
        if zero_init_output:
            # f starts constant, so ω starts as alpha_scale·α (mass ≈ 2.4 for a circle of radius 0.6)
            # instead of as the random network's gradient, which is 15–40× larger than α: measured here,
            # the mass bound after 1000 CPU steps was 1.56 with and 1.97 without (disk area 1.13)
            nn.init.zeros_(self.mlp.net[-1].weight)
            nn.init.zeros_(self.mlp.net[-1].bias[1:])  # the harmonics' coefficients too (none without them)
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
        if self.phase_harmonics:
            return (self.mlp(features) * self.phase_basis(x)[0]).sum(-1)
        return self.mlp(features).squeeze(-1)

    @property
    def follows_progress(self) -> bool:
        """Whether training must call ``set_progress`` (harmonics that open later)."""
        return self.phase_harmonics > 0 and self.phase_harmonics_start > 0

    def set_progress(self, progress: float) -> None:
        """The harmonics' gate at the fraction ``progress`` ∈ [0, 1] of the training budget: 0 before
        ``phase_harmonics_start``, then linear to 1 over ``HARMONICS_RAMP``."""
        if self.follows_progress:
            self.harmonic_gate.fill_(min(max((progress - self.phase_harmonics_start) / self.HARMONICS_RAMP, 0.0), 1.0))

    def phase_basis(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The outputs' basis with phase harmonics: e = [1, g·a·cos(ku)/k, g·a·sin(ku)/k]_{k=1..K} and its
        derivative ∂e/∂u = [0, −g·a·sin(ku), g·a·cos(ku)], a = alpha_scale, g the gate (``set_progress``),
        u = Ω_Γ(x)/2 (∇u = α_Γ/2). (N, 3) → 2 × (N, 2K + 1), no gradient (e enters f = Σ_m h_m e_m as data; its
        x-derivative is added through α)."""
        with torch.no_grad():
            if float(self.harmonic_gate) == 0.0:  # not open yet: f = h_0, and no solid angle to compute
                basis = x.new_zeros(x.shape[0], 1 + 2 * self.phase_harmonics)
                basis[:, 0] = 1.0
                return basis, torch.zeros_like(basis)
            u = 0.5 * solid_angle(x.detach(), self.loops)
            k = torch.arange(1, self.phase_harmonics + 1, dtype=x.dtype, device=x.device)
            ku = u[:, None] * k
            cos, sin = torch.cos(ku), torch.sin(ku)
            a = self.alpha_scale * self.harmonic_gate.to(x.dtype)
            ones = torch.ones_like(u)[:, None]
            basis = torch.cat([ones, cos * (a / k), sin * (a / k)], dim=1)
            slope = torch.cat([torch.zeros_like(ones), sin * -a, cos * a], dim=1)
        return basis, slope

    def field(self, x: torch.Tensor) -> torch.Tensor:
        """α_Γ(x) unscaled, closed form (``geometry.biot_savart``). (N, d) → (N, d)."""
        if self.dim == 3:
            return biot_savart(x, self.loops)
        return biot_savart_2d(x, self.poles, self.signs)

    def alpha(self, x: torch.Tensor) -> torch.Tensor:
        """alpha_scale · α_Γ(x), closed form. (N, d) → (N, d)."""
        return self.alpha_scale * self.field(x)

    def forward(self, x: torch.Tensor, create_graph: bool = True,
                alpha: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """(f, ω) at points x: (N, d) → ((N,), (N, d)). ``create_graph`` for training (double backward).
        ``alpha`` (N, d): the unscaled α_Γ(x) if already known (a sample pool), else computed here.

        ∇f and its training backward are written out by hand (``nn.field_gradient``); with
        ``gradient="autograd"``, ∇f is taken by autograd through the MLP to its input features, then through the
        Fourier features by their closed-form Jacobian. Same numbers either way (tests/test_nn.py).
        """
        x = x.detach()
        field = self.field(x) if alpha is None else alpha
        basis = slope = None
        if self.phase_harmonics:
            basis, slope = self.phase_basis(x)
        # the hand-written pass: the MLP on the Fourier features and, if any, the grid features after them
        extra_dim = self.grid.out_dim if self.grid is not None else 0
        if self.gradient == "closed_form" and closed_form_supported(self.mlp, self.encoding, extra_dim=extra_dim,
                                                                    out_dim=1 + 2 * self.phase_harmonics):
            with torch.set_grad_enabled(create_graph and torch.is_grad_enabled()):
                f, grad_f = field_and_gradient(self.mlp, self.encoding, x, grid=self.grid,
                                               matmul_precision=self.matmul_precision, output_basis=basis)
                if basis is None:
                    return f, grad_f + self.alpha_scale * field
                return self._harmonic_current(f, grad_f, basis, slope, field)
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
            h = self.mlp(torch.cat(parts, dim=-1) if len(parts) > 1 else parts[0])
            f = h.squeeze(-1) if basis is None else h
            weighted = f if basis is None else (h * basis).sum(-1)
            grads = torch.autograd.grad(weighted.sum(), wrt, create_graph=create_graph)
            grad_f = self.encoding.input_gradient(grads[0], sin, cos) if self.encoding.enabled else grads[0]
            if self.grid is not None:
                grad_f = grad_f + torch.einsum("nk,nkd->nd", grads[1], grid_jacobian)
        if not create_graph:
            f, grad_f = f.detach(), grad_f.detach()
        if basis is None:
            return f, grad_f + self.alpha_scale * field
        return self._harmonic_current(f, grad_f, basis, slope, field)

    def _harmonic_current(self, h: torch.Tensor, grad_h: torch.Tensor, basis: torch.Tensor, slope: torch.Tensor,
                          field: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(f, ω) from the outputs h (N, M) and Σ_m e_m ∇h_m (N, 3): f = h·e, and ∇f gains (h·∂e/∂u)·∇u with
        ∇u = α_Γ/2, which joins α itself: ω = Σ_m e_m ∇h_m + (alpha_scale + (h·∂e/∂u)/2)·α_Γ."""
        f = (h * basis).sum(-1)
        return f, grad_h + (self.alpha_scale + 0.5 * (h * slope).sum(-1, keepdim=True)) * field

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
