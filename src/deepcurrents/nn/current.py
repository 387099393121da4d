"""The neural current ω = ∇f_θ + alpha_scale · α_Γ (paper eq. alpha-hodge)."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager

import torch
from torch import nn

from deepcurrents.errors import ConfigError
from deepcurrents.geometry import angle_2d, biot_savart, biot_savart_2d
from deepcurrents.geometry.biot_savart import segment_table, solid_angle
from deepcurrents.geometry.phase_map import von_mises_offset, von_mises_slope
from deepcurrents.nn.field_gradient import check_matmul_precision, closed_form_supported, field_and_gradient
from deepcurrents.nn.fourier import FourierFeatures
from deepcurrents.nn.grid_encoding import MultiresGrid
from deepcurrents.nn.mlp import FieldMLP


def spatial_gradient(f: torch.Tensor, x: torch.Tensor, create_graph: bool) -> torch.Tensor:
    """∂f/∂x by autograd, per sample. f: (N,) computed row-wise from x: (N, D) with requires_grad → (N, D)."""
    (grad,) = torch.autograd.grad(f.sum(), x, create_graph=create_graph)
    return grad


def budget_fraction(key: str, value: object) -> float:
    """``model.net.<key>``, a fraction of the training budget in [0, 1), or one sentence (ConfigError)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0.0 <= value < 1.0:
        raise ConfigError(f"model.net.{key}={value} must be a fraction of the training budget in [0, 1).")
    return float(value)


def _read_state_after_loading(module: NeuralCurrent, incompatible_keys) -> None:
    """``load_state_dict``'s post-hook: the buffers may have changed (``NeuralCurrent._read_state``)."""
    module._read_state()


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
    ``phase_sharpening`` κ > 0 (beyond the paper; experimental, in no preset: README "Recipes"): the current is
    the network's current concentrated onto one level of its own phase, ω = ψ'(φ)·(∇f_θ + alpha_scale·α) and
    f = f_θ + 2·alpha_scale·(ψ(φ) − φ), with φ = f_θ/(2·alpha_scale) + Ω_Γ/2 the network's phase and ψ the von
    Mises map of the circle around a level c (``geometry.phase_map``; in 2D φ = f_θ/alpha_scale + Σ_j s_j·angle(x − p_j)
    and f = f_θ + alpha_scale·(ψ(φ) − φ)). ω is again a current with boundary Γ, and by the coarea formula its mass
    is the ψ'-weighted mean of the areas of the level sets {φ = t} near c, where the plain current's mass is their
    plain mean: the far levels of a smeared jump (bulged caps) stop counting, and the loss works on the level sets
    next to c. c is set once, when the sharpening opens, to θ + π with θ the circular mean of φ over fixed points
    (the phase off the surface, as the mesher's level; ``_open_sharpening``); φ is taken without f_θ's output bias
    (a constant turn of every level). κ grows linearly from 0 after ``phase_sharpening_start`` of the budget over
    the next ``HARMONICS_RAMP`` (``set_progress``). The loss then moves level sets through f_θ's values, which few
    uniform samples see: train it with importance samples (``data.sampling.kind=importance``).
    """

    HARMONICS_RAMP = 0.2  # also the sharpening's ramp

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
        phase_sharpening: float = 0.0,
        phase_sharpening_start: float = 0.0,
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
        budget_fraction("phase_harmonics_start", phase_harmonics_start)
        kappa = float(phase_sharpening) if isinstance(phase_sharpening, (int, float)) else float("nan")
        if isinstance(phase_sharpening, bool) or not 0.0 <= kappa < float("inf"):
            raise ConfigError(f"model.net.phase_sharpening={phase_sharpening!r} must be a concentration κ ≥ 0 "
                              "(0: off).")
        self.phase_sharpening = kappa
        self.phase_sharpening_start = budget_fraction("phase_sharpening_start", phase_sharpening_start)
        if kappa:  # the present κ and the level c (NaN until the sharpening opens): buffers, so checkpoints keep them
            self.register_buffer("sharpening", torch.tensor(0.0 if self.phase_sharpening_start > 0 else kappa))
            self.register_buffer("sharpening_level", torch.tensor(float("nan")))
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
        self._read_state()
        self.register_load_state_dict_post_hook(_read_state_after_loading)

    def _read_state(self) -> None:
        """Python copies of the buffers that the forward branches on (the loops' sizes, the harmonics' gate, κ and
        whether the level c is set), read once here and after a checkpoint loads: read from the buffers in every
        step, they would make a GPU step wait for the device (a synchronisation) once per read. The buffers stay the
        checkpoint's record; they change only through ``set_progress``, ``unsharpened`` and ``_open_sharpening``,
        which keep both. Also forgets α's segment tables (``field``), which follow the loops; nothing else
        writes the loops."""
        self._loop_sizes = self.loop_sizes.tolist() if self.dim == 3 else []
        self._segments = {}  # (dtype, device) → the loops' biot_savart.segment_table, made on first use
        self._gate = float(self.harmonic_gate) if self.phase_harmonics else 0.0
        self._kappa = float(self.sharpening) if self.phase_sharpening else 0.0
        self._level_set = bool(self.phase_sharpening) and not torch.isnan(self.sharpening_level).item()

    @property
    def loops(self) -> list[torch.Tensor]:
        """The boundary loops, list of (M_i, 3) (3D only)."""
        return list(torch.split(self.vertices, self._loop_sizes))

    def f(self, x: torch.Tensor) -> torch.Tensor:
        """The scalar field f (the network's f_θ, through the harmonics and the sharpening if any). (N, d) → (N,)."""
        u = self._boundary_angle(x)
        f = self._network_f(x, u)
        return f if u is None or not self.phase_sharpening else self._sharpen(f, None, u)[0]

    def _network_f(self, x: torch.Tensor, u: torch.Tensor | None) -> torch.Tensor:
        """f_θ of the network (with its harmonics, before any sharpening); u from ``_boundary_angle``.
        (N, d) → (N,)."""
        features = self.encoding(x)
        if self.grid is not None:
            features = torch.cat([features, self.grid(x)], dim=-1)
        if self.phase_harmonics:
            return (self.mlp(features) * self.phase_basis(x, u)[0]).sum(-1)
        return self.mlp(features).squeeze(-1)

    @property
    def follows_progress(self) -> bool:
        """Whether training must call ``set_progress`` (harmonics or a sharpening that open later)."""
        return (self.phase_harmonics > 0 and self.phase_harmonics_start > 0) or (
            self.phase_sharpening > 0 and self.phase_sharpening_start > 0)

    def set_progress(self, progress: float) -> None:
        """The harmonics' gate and the sharpening's κ at the fraction ``progress`` ∈ [0, 1] of the training
        budget: 0 before their start, then linear to full over ``HARMONICS_RAMP``."""
        def opened(start: float) -> float:
            return min(max((progress - start) / self.HARMONICS_RAMP, 0.0), 1.0)
        if self.phase_harmonics and self.phase_harmonics_start > 0:
            self._gate = opened(self.phase_harmonics_start)
            self.harmonic_gate.fill_(self._gate)
        if self.phase_sharpening and self.phase_sharpening_start > 0:
            self._set_kappa(self.phase_sharpening * opened(self.phase_sharpening_start))

    def _set_kappa(self, kappa: float) -> None:
        """The sharpening's present κ, in its buffer and in the copy the forward reads (``_read_state``)."""
        self._kappa = float(kappa)
        self.sharpening.fill_(self._kappa)

    def _boundary_angle(self, x: torch.Tensor) -> torch.Tensor | None:
        """u, the boundary's part of the phase, where the harmonics or the sharpening need it now, else None:
        Ω_Γ(x)/2 in 3D (∇u = α/2), Σ_j s_j·angle(x − p_j) in 2D (∇u = α). (N, d) → (N,), no gradient."""
        if not (self._gate > 0.0 or self._kappa > 0.0):
            return None
        with torch.no_grad():
            x = x.detach()
            return 0.5 * solid_angle(x, self.loops) if self.dim == 3 else angle_2d(x, self.poles, self.signs)

    def _sharpen(self, f: torch.Tensor, omega: torch.Tensor | None, u: torch.Tensor
                 ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """The network's (f, ω) concentrated onto the level c of its phase (class docstring): (ψ-shifted f,
        ψ'(φ)·ω). f (N,), ω (N, d) or None, u (N,) from ``_boundary_angle`` → ((N,), (N, d) or None);
        differentiable in f and ω."""
        kappa = self._kappa
        if kappa == 0.0:  # not open yet (or read unsharpened): ψ is the identity, and c is not set before it opens
            return f, omega
        phase = self._network_phase(f, u)
        if not self._level_set:
            self._open_sharpening()
        level = self.sharpening_level.to(phase.dtype)
        f = f + self._phase_unit * von_mises_offset(phase, level, kappa)
        return f, None if omega is None else von_mises_slope(phase, level, kappa)[:, None] * omega

    def phase_basis(self, x: torch.Tensor, u: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """The outputs' basis with phase harmonics: e = [1, g·a·cos(ku)/k, g·a·sin(ku)/k]_{k=1..K} and its
        derivative ∂e/∂u = [0, −g·a·sin(ku), g·a·cos(ku)], a = alpha_scale, g the gate (``set_progress``),
        u = Ω_Γ(x)/2 (∇u = α_Γ/2; computed here unless given, (N,)). (N, 3) → 2 × (N, 2K + 1), no gradient (e
        enters f = Σ_m h_m e_m as data; its x-derivative is added through α)."""
        with torch.no_grad():
            if self._gate == 0.0:  # not open yet: f = h_0, and no solid angle to compute
                basis = x.new_zeros(x.shape[0], 1 + 2 * self.phase_harmonics)
                basis[:, 0] = 1.0
                return basis, torch.zeros_like(basis)
            if u is None:
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
            key = (x.dtype, x.device)
            if key not in self._segments:  # Γ is fixed: its segments once, not in every step
                self._segments[key] = segment_table(self.loops, x.dtype, x.device)
            return biot_savart(x, segments=self._segments[key])
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
        u = self._boundary_angle(x)
        basis = slope = None
        if self.phase_harmonics:
            basis, slope = self.phase_basis(x, u)
        f, omega = self._network_current(x, field, basis, slope, create_graph)
        if u is not None and self.phase_sharpening:
            with torch.set_grad_enabled(create_graph and torch.is_grad_enabled()):
                f, omega = self._sharpen(f, omega, u)
        return f, omega

    def _network_current(self, x: torch.Tensor, field: torch.Tensor, basis: torch.Tensor | None,
                         slope: torch.Tensor | None, create_graph: bool) -> tuple[torch.Tensor, torch.Tensor]:
        """(f, ω) of the network itself (``forward`` before any sharpening): x (N, d), α_Γ(x) (N, d), the
        harmonics' basis and slope (N, 2K + 1) or None → ((N,), (N, d))."""
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

    @contextmanager
    def unsharpened(self) -> Iterator[NeuralCurrent]:
        """This module as the network's own current (κ = 0) inside the context. ψ is monotone, so the sharpened
        current's level sets are those of the network's phase φ, which is smooth where ψ∘φ is steep: the mesher's
        coarse cells and Newton steps assume a smooth phase (meshed sharpened, a trefoil came out 0.861 with its
        border 0.068 off Γ; the same checkpoint meshed through φ, 0.7367)."""
        if not self.phase_sharpening:
            yield self
            return
        kappa = self._kappa
        self._set_kappa(0.0)
        try:
            yield self
        finally:
            self._set_kappa(kappa)

    @property
    def _phase_unit(self) -> float:
        """f per radian of phase: the jump of f across the surface is 2π times it (2·alpha_scale in 3D)."""
        return (2.0 if self.dim == 3 else 1.0) * self.alpha_scale

    def _network_phase(self, f: torch.Tensor, u: torch.Tensor) -> torch.Tensor:
        """φ = (f_θ − b)/unit + u, the network's phase without its output bias b: b turns every level alike, and
        left in, the loss would pass Adam a gradient for it whose steps of about lr turn the phase by lr/unit ≈ 1 rad
        a step. f (N,), u (N,) → (N,), differentiable in f."""
        return (f - self.mlp.net[-1].bias[0]) / self._phase_unit + u

    @torch.no_grad()
    def _open_sharpening(self, probes: int = 4096) -> None:
        """Sets the sharpening's level c = θ + π, θ the circular mean of the network's phase (without its output
        bias) over fixed quasi-random points of [-1, 1]^d: the phase off the surface, where most points are (the
        mesher's level likewise). The same points on every DDP rank and at every resume, so c is too."""
        weight = self.mlp.net[-1].weight
        x = torch.quasirandom.SobolEngine(self.dim, scramble=True, seed=0).draw(probes).to(weight) * 2.0 - 1.0
        u = self._boundary_angle(x)
        phase = self._network_phase(self._network_f(x, u), u)
        theta = torch.atan2(torch.sin(phase).mean(), torch.cos(phase).mean())
        self.sharpening_level.fill_(float(theta) + torch.pi)
        self._level_set = True

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
