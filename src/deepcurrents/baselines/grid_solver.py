"""Minimal currents on a voxel grid (Wang & Chern 2021, the grid method of paper Fig. 4), pure tensors.

The problem is the paper's ``min_φ ‖dφ + α‖₁`` over U = [-1, 1]³, with φ a grid function instead of a
network. It is solved by ADMM on the split ``Z = Gφ + α``:

    φ ← argmin ‖Gφ − (Z − α − u)‖²_W          (a Poisson equation, solved exactly by fast cosine transforms)
    Z ← shrink(Gφ + α + u, 1/ρ)               (vector soft threshold, pointwise)
    u ← u + Gφ + α − Z                        (scaled multiplier, u = Λ/ρ)

Discretisation (why it is this one). U is not periodic: α does not vanish on ∂U and φ is free there
(natural, Neumann boundary condition). Padding a periodic FFT box would cost a larger grid and still
couple opposite faces through the wrap-around, so we use the Neumann discretisation that cosine
transforms diagonalise exactly:

- φ lives at the N³ **cell centres** (the voxels: N³ parameters, 90³ ≈ the network's 725,249);
- Z, α and u live at the (N+1)³ **cell corners** (grid vertices, ∂U included);
- G is the gradient of φ's trilinear interpolant at the corners: the difference along one axis
  averaged over the four neighbouring cells across the other two, with φ reflected across ∂U
  (ghost cell = its neighbour, so G's normal component vanishes on ∂U: the Neumann condition);
- W holds the trapezoid-rule weights of the corners (½ per axis on ∂U), so ``Σ W |ω| h³`` is the
  trapezoid rule for ∫_U |ω| and the shrink step stays pointwise (W factors out per vertex).

With these choices GᵀWG is diagonal in the 3D DCT-II basis with eigenvalues
``(4/h²)(s_k c_l c_m + c_k s_l c_m + c_k c_l s_m)``, s_k = sin²(πk/2N), c_k = cos²(πk/2N),
which vanish only for the constant mode: the φ-step is exact, with no checkerboard null space.
The DCT is computed with torch FFTs (Makhoul's reordering), so everything runs on CPU or GPU.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

DIMS = (0, 1, 2)


# ---------------------------------------------------------------------------------------------------
# fast cosine transforms (orthonormal DCT-II and its inverse), along one or all three axes


def dct(x: torch.Tensor, dim: int) -> torch.Tensor:
    """Orthonormal DCT-II along ``dim`` (scipy's ``dct(x, type=2, norm="ortho")``), via one FFT."""
    n = x.shape[dim]
    spec = torch.fft.fft(_even_odd(x, dim), dim=dim)
    k = torch.arange(n, device=x.device, dtype=x.dtype)
    twiddle = torch.polar(torch.ones_like(k), -math.pi * k / (2 * n))
    out = (spec * _along(twiddle, dim, x.ndim)).real
    scale = torch.full((n,), math.sqrt(2.0 / n), device=x.device, dtype=x.dtype)
    scale[0] = math.sqrt(1.0 / n)
    return out * _along(scale, dim, x.ndim)


def idct(y: torch.Tensor, dim: int) -> torch.Tensor:
    """Inverse of :func:`dct` (orthonormal DCT-III) along ``dim``."""
    n = y.shape[dim]
    scale = torch.full((n,), math.sqrt(n / 2.0), device=y.device, dtype=y.dtype)
    scale[0] = math.sqrt(float(n))
    z = y * _along(scale, dim, y.ndim)  # un-normalised: z_k = Σ x_j cos(πk(2j+1)/2N)
    # z_{N-k} for k = 1..N-1, and 0 for k = 0
    flipped = torch.cat([torch.zeros_like(z.narrow(dim, 0, 1)), z.narrow(dim, 1, n - 1).flip(dim)], dim)
    k = torch.arange(n, device=y.device, dtype=y.dtype)
    twiddle = _along(torch.polar(torch.ones_like(k), math.pi * k / (2 * n)), dim, y.ndim)
    v = torch.fft.ifft(twiddle * torch.complex(z, -flipped), dim=dim).real
    half = (n + 1) // 2
    out = torch.empty_like(v)
    even = torch.arange(0, n, 2, device=y.device)
    odd = torch.arange(1, n, 2, device=y.device)
    out.index_copy_(dim, even, v.narrow(dim, 0, half))
    out.index_copy_(dim, odd, v.narrow(dim, half, n - half).flip(dim))
    return out


def dctn(x: torch.Tensor, dims=DIMS) -> torch.Tensor:
    """Orthonormal DCT-II along each of ``dims``."""
    for d in dims:
        x = dct(x, d)
    return x


def idctn(y: torch.Tensor, dims=DIMS) -> torch.Tensor:
    """Inverse of :func:`dctn`."""
    for d in dims:
        y = idct(y, d)
    return y


def _even_odd(x: torch.Tensor, dim: int) -> torch.Tensor:
    """Makhoul's reordering: even-indexed entries ascending, then odd-indexed ones descending."""
    n = x.shape[dim]
    even = torch.arange(0, n, 2, device=x.device)
    odd = torch.arange(1, n, 2, device=x.device).flip(0)
    return torch.cat([x.index_select(dim, even), x.index_select(dim, odd)], dim)


def _along(v: torch.Tensor, dim: int, ndim: int) -> torch.Tensor:
    """A 1D tensor shaped to broadcast along axis ``dim`` of an ``ndim``-tensor."""
    shape = [1] * ndim
    shape[dim] = -1
    return v.reshape(shape)


# ---------------------------------------------------------------------------------------------------
# the grid: cells, corners, trapezoid weights


def grid_spacing(resolution: int) -> float:
    """h, the edge of one of the N³ cells of [-1, 1]³."""
    return 2.0 / resolution


def cell_centers(resolution: int, device=None, dtype=torch.float64) -> torch.Tensor:
    """Centres of the N³ cells, where φ lives: (N, N, N, 3), axis i of the array = coordinate i."""
    h = grid_spacing(resolution)
    axis = -1.0 + h * (torch.arange(resolution, device=device, dtype=dtype) + 0.5)
    return torch.stack(torch.meshgrid(axis, axis, axis, indexing="ij"), -1)


def grid_vertices(resolution: int, device=None, dtype=torch.float64) -> torch.Tensor:
    """Corners of the cells (∂U included), where Z, α and u live: (N+1, N+1, N+1, 3)."""
    axis = torch.linspace(-1.0, 1.0, resolution + 1, device=device, dtype=dtype)
    return torch.stack(torch.meshgrid(axis, axis, axis, indexing="ij"), -1)


def trapezoid_weights(resolution: int, device=None, dtype=torch.float64) -> torch.Tensor:
    """Trapezoid-rule weights of the corners (1 inside, ½ per axis on ∂U): (N+1, N+1, N+1); Σ = N³."""
    w = torch.ones(resolution + 1, device=device, dtype=dtype)
    w[0] = w[-1] = 0.5
    return w[:, None, None] * w[None, :, None] * w[None, None, :]


# ---------------------------------------------------------------------------------------------------
# the discrete d (G) and its adjoint


def _reflect(x: torch.Tensor, dim: int) -> torch.Tensor:
    """Adds one ghost cell at each end of ``dim`` equal to its neighbour (Neumann reflection)."""
    return torch.cat([x.narrow(dim, 0, 1), x, x.narrow(dim, -1, 1)], dim)


def _reflect_adjoint(g: torch.Tensor, dim: int) -> torch.Tensor:
    """Adjoint of :func:`_reflect`: the ghosts' values are added back to the cells they copy."""
    n = g.shape[dim] - 2
    core = g.narrow(dim, 1, n).clone()
    core.narrow(dim, 0, 1).add_(g.narrow(dim, 0, 1))
    core.narrow(dim, n - 1, 1).add_(g.narrow(dim, n + 1, 1))
    return core


def _diff(x: torch.Tensor, dim: int) -> torch.Tensor:
    n = x.shape[dim]
    return x.narrow(dim, 1, n - 1) - x.narrow(dim, 0, n - 1)


def _mean2(x: torch.Tensor, dim: int) -> torch.Tensor:
    n = x.shape[dim]
    return 0.5 * (x.narrow(dim, 1, n - 1) + x.narrow(dim, 0, n - 1))


def _zero_pad(x: torch.Tensor, dim: int) -> torch.Tensor:
    zero = torch.zeros_like(x.narrow(dim, 0, 1))
    return torch.cat([zero, x, zero], dim)


def _diff_adjoint(z: torch.Tensor, dim: int) -> torch.Tensor:
    """Adjoint of :func:`_diff`: out[i] = z[i−1] − z[i] (zero outside)."""
    zp = _zero_pad(z, dim)
    n = zp.shape[dim]
    return zp.narrow(dim, 0, n - 1) - zp.narrow(dim, 1, n - 1)


def _mean2_adjoint(z: torch.Tensor, dim: int) -> torch.Tensor:
    zp = _zero_pad(z, dim)
    n = zp.shape[dim]
    return 0.5 * (zp.narrow(dim, 0, n - 1) + zp.narrow(dim, 1, n - 1))


def grid_gradient(phi: torch.Tensor, h: float) -> torch.Tensor:
    """G φ: the gradient of φ's trilinear interpolant at the cell corners, φ reflected across ∂U.

    phi (N, N, N) at cell centres → (3, N+1, N+1, N+1) at corners (component first).
    """
    p = phi
    for d in DIMS:
        p = _reflect(p, d)
    comps = []
    for c in DIMS:
        g = _diff(p, c)
        for d in DIMS:
            if d != c:
                g = _mean2(g, d)
        comps.append(g)
    return torch.stack(comps, 0) / h


def grid_gradient_adjoint(z: torch.Tensor, h: float) -> torch.Tensor:
    """Gᵀ z (plain Euclidean adjoint of :func:`grid_gradient`). z (3, N+1, N+1, N+1) → (N, N, N)."""
    total = None
    for c in DIMS:
        g = z[c]
        for d in DIMS:
            if d != c:
                g = _mean2_adjoint(g, d)
        g = _diff_adjoint(g, c)
        total = g if total is None else total + g
    for d in DIMS:
        total = _reflect_adjoint(total, d)
    return total / h


# ---------------------------------------------------------------------------------------------------
# the φ-step: GᵀWG φ = rhs, exactly, by cosine transforms


def poisson_eigenvalues(resolution: int, h: float, device=None, dtype=torch.float64) -> torch.Tensor:
    """Eigenvalues of GᵀWG in the 3D DCT-II basis: (N, N, N); only the constant mode [0, 0, 0] is 0."""
    k = torch.arange(resolution, device=device, dtype=dtype)
    s = torch.sin(math.pi * k / (2 * resolution)) ** 2
    c = 1.0 - s
    sx, sy, sz = s[:, None, None], s[None, :, None], s[None, None, :]
    cx, cy, cz = c[:, None, None], c[None, :, None], c[None, None, :]
    return (4.0 / h**2) * (sx * cy * cz + cx * sy * cz + cx * cy * sz)


def solve_poisson(rhs: torch.Tensor, eigenvalues: torch.Tensor) -> torch.Tensor:
    """The mean-free φ with GᵀWG φ = rhs (the constant mode of rhs is dropped). (N, N, N) → (N, N, N)."""
    spec = dctn(rhs)
    safe = torch.where(eigenvalues > 0, eigenvalues, torch.ones_like(eigenvalues))
    spec = torch.where(eigenvalues > 0, spec / safe, torch.zeros_like(spec))
    return idctn(spec)


# ---------------------------------------------------------------------------------------------------
# the Z-step, the objective, ADMM


def pointwise_norm(v: torch.Tensor) -> torch.Tensor:
    """|v| of a component-first field. (d, ...) → (...)."""
    return torch.sqrt(sum(c * c for c in v.unbind(0)))


def shrink(v: torch.Tensor, tau: float | torch.Tensor) -> torch.Tensor:
    """Vector soft threshold, the prox of τ|·|: v · max(0, 1 − τ/|v|) pointwise. (d, ...) → (d, ...)."""
    norm = pointwise_norm(v).clamp_min(torch.finfo(v.dtype).tiny)
    return v * torch.clamp(1.0 - tau / norm, min=0.0)


def cap_singularity(alpha: torch.Tensor, h: float) -> torch.Tensor:
    """Caps |α| at 8/h, the mean of |α| ≈ 2/r over a disc of radius h/2 around Γ. (3, ...) → (3, ...).

    α ~ 2/r near Γ: a corner that happens to lie within ~h/4 of Γ would otherwise put an unbounded
    weight h³·2/r into the discrete mass (a corner exactly on Γ, e.g. on a circle through grid
    points, can add more than the whole area). The cap only touches corners closer than h/4.
    """
    norm = pointwise_norm(alpha).clamp_min(torch.finfo(alpha.dtype).tiny)
    return alpha * torch.clamp((8.0 / h) / norm, max=1.0)


@dataclass
class GridProblem:
    """min_φ Σ W |Gφ + α| h³ on N³ cells of [-1, 1]³. alpha (3, N+1, N+1, N+1) sampled at the corners."""

    alpha: torch.Tensor
    weights: torch.Tensor
    eigenvalues: torch.Tensor
    h: float

    def __post_init__(self) -> None:
        self.alpha_norm = self.norm(self.alpha)

    @classmethod
    def from_alpha(cls, alpha: torch.Tensor) -> GridProblem:
        n = alpha.shape[1] - 1
        h = grid_spacing(n)
        return cls(alpha, trapezoid_weights(n, alpha.device, alpha.dtype),
                   poisson_eigenvalues(n, h, alpha.device, alpha.dtype), h)

    @property
    def resolution(self) -> int:
        return self.alpha.shape[1] - 1

    def norm(self, field: torch.Tensor) -> float:
        """Weighted L2 norm (Σ W |field|² h³)^½ of a corner field (3, N+1, N+1, N+1)."""
        sq = sum(c * c for c in field.unbind(0))
        return float(torch.dot(sq.flatten(), self.weights.flatten()).sqrt()) * self.h**1.5

    def mass(self, omega: torch.Tensor) -> float:
        """Discrete mass Σ W |ω| h³ (trapezoid rule for ∫_U |ω|) of a corner field (3, N+1, N+1, N+1)."""
        return float(torch.dot(pointwise_norm(omega).flatten(), self.weights.flatten())) * self.h**3

    def current(self, phi: torch.Tensor) -> torch.Tensor:
        """ω = Gφ + α at the corners. (N, N, N) → (3, N+1, N+1, N+1)."""
        return grid_gradient(phi, self.h) + self.alpha

    def least_squares(self, target: torch.Tensor) -> torch.Tensor:
        """argmin_φ ‖Gφ − target‖_W (mean-free). target (3, N+1, N+1, N+1) → (N, N, N)."""
        rhs = grid_gradient_adjoint(target * self.weights, self.h)
        return solve_poisson(rhs, self.eigenvalues)

    def dual_bound(self, multiplier: torch.Tensor) -> float:
        """A certified lower bound of min_φ mass(Gφ + α) from a multiplier Λ (corner field).

        Λ is projected onto GᵀWΛ = 0 and scaled into |Λ| ≤ 1; then mass(Gφ + α) ≥ ⟨Λ, α⟩_W h³ for
        every φ (weak duality), whatever state the iteration stopped in.
        """
        lam = multiplier - grid_gradient(self.least_squares(multiplier), self.h)
        lam = lam / max(1.0, float(pointwise_norm(lam).max()))
        return float(((lam * self.alpha).sum(0) * self.weights).sum()) * self.h**3


@dataclass
class ADMMState:
    """φ (N, N, N); Z and the scaled multiplier u = Λ/ρ (3, N+1, N+1, N+1); the penalty ρ; the count."""

    phi: torch.Tensor
    z: torch.Tensor
    u: torch.Tensor
    rho: float
    iteration: int = 0


@dataclass
class ADMMReport:
    """One iteration's numbers: relative primal/dual residuals, the mass of Gφ + α, ρ after balancing."""

    primal: float
    dual: float
    mass: float
    rho: float


def admm_init(problem: GridProblem, rho: float) -> ADMMState:
    """φ = 0, Z = α, u = 0."""
    n = problem.resolution
    phi = torch.zeros((n, n, n), device=problem.alpha.device, dtype=problem.alpha.dtype)
    return ADMMState(phi, problem.alpha.clone(), torch.zeros_like(problem.alpha), float(rho))


def admm_step(problem: GridProblem, state: ADMMState, relaxation: float = 1.0, balance: float = 10.0,
              factor: float = 2.0) -> ADMMReport:
    """One ADMM iteration on ``state`` (updated in place) → residuals (Boyd et al. 2011, §3.3–3.4).

    ``relaxation`` ∈ [1, 1.9) is over-relaxation (Boyd §3.4.3): Gφ + α is replaced by its blend with the
    previous Z in the Z- and u-updates.
    Residuals are relative: primal ‖Gφ + α − Z‖_W / max(‖Gφ‖, ‖Z‖, ‖α‖), dual ρ‖Z − Z_prev‖_W / ‖ρu‖_W.
    ρ is rebalanced (×/÷ ``factor``) when one residual exceeds ``balance`` × the other (0 disables it).
    """
    phi = problem.least_squares(state.z - problem.alpha - state.u)
    grad = grid_gradient(phi, problem.h)
    omega = grad + problem.alpha
    relaxed = omega if relaxation == 1.0 else relaxation * omega + (1.0 - relaxation) * state.z
    z = shrink(relaxed + state.u, 1.0 / state.rho)
    r = omega - z
    dz = z - state.z
    state.u.add_(relaxed - z)
    state.phi, state.z = phi, z
    state.iteration += 1
    scale = max(problem.norm(grad), problem.norm(z), problem.alpha_norm, 1e-300)
    primal = problem.norm(r) / scale
    dual = problem.norm(dz) / max(problem.norm(state.u), 1e-300)
    if balance > 0 and primal > balance * dual:
        state.rho *= factor
        state.u.div_(factor)
    elif balance > 0 and dual > balance * primal:
        state.rho /= factor
        state.u.mul_(factor)
    return ADMMReport(primal, dual, problem.mass(omega), state.rho)
