"""The grid baseline's current and optimiser: a grid function φ seen as a current (for the shared meshing and
metrics) and the ADMM solver (``deepcurrents.baselines.grid_solver``) wrapped as a torch optimiser, so the
grid goes through the same Lightning loop, checkpoints and resume as the network."""

from __future__ import annotations

from collections.abc import Callable

import torch
import torch.nn.functional as F
from torch import nn

from deepcurrents.baselines.grid_solver import (
    ADMMReport,
    ADMMState,
    GridProblem,
    admm_step,
    grid_gradient,
    grid_spacing,
)
from deepcurrents.geometry import biot_savart

DTYPES = {"float32": torch.float32, "float64": torch.float64}


class GridCurrent(nn.Module):
    """A grid function φ on the N³ cells of [-1, 1]³ as a current, for the network's meshing and metrics.

    The grid's current is ω_c = Gφ + alpha_scale·α_Γ at the cell corners (what ADMM minimises). Between
    samples both are trilinear: f(x) interpolates φ between cell centres (constant past the outer ones,
    like the solver's Neumann reflection) and ω(x) interpolates ω_c between corners. Same normalisation
    as ``NeuralCurrent`` (ω = ∇f + alpha_scale·α), so the same level, |ω| ≥ δ cut and Newton steps apply.
    (∇f + alpha_scale·α(x) off the corners would mix the grid's gradient with the exact singular α,
    which the grid cannot cancel between its samples: spurious |ω| next to Γ.)

    φ is the only parameter (frozen for autograd: ADMM updates it in place). ``corner_alpha`` (scaled)
    is set by its owner with :meth:`set_corner_alpha`.
    """

    def __init__(self, resolution: int, loops: list[torch.Tensor], alpha_scale: float = 1e-3,
                 dtype: torch.dtype = torch.float64):
        super().__init__()
        self.dim = 3
        self.alpha_scale = alpha_scale
        self.phi = nn.Parameter(torch.zeros(resolution, resolution, resolution, dtype=dtype), requires_grad=False)
        self.register_buffer("vertices", torch.cat([torch.as_tensor(lp) for lp in loops]).double())
        self.register_buffer("loop_sizes", torch.tensor([len(lp) for lp in loops], dtype=torch.long))
        self.register_buffer("corner_alpha", None, persistent=False)
        self._cache: tuple | None = None

    @property
    def resolution(self) -> int:
        return self.phi.shape[0]

    @property
    def loops(self) -> list[torch.Tensor]:
        """The boundary loops, list of (M_i, 3)."""
        return list(torch.split(self.vertices, self.loop_sizes.tolist()))

    def set_corner_alpha(self, alpha: torch.Tensor) -> None:
        """alpha_scale·α_Γ sampled at the corners, (3, N+1, N+1, N+1)."""
        self.corner_alpha = alpha.to(self.phi)
        self._cache = None

    def corner_current(self) -> torch.Tensor:
        """ω_c = Gφ + alpha_scale·α at the corners: (3, N+1, N+1, N+1) (cached until φ changes)."""
        if self.corner_alpha is None:
            raise RuntimeError("GridCurrent.corner_alpha is not set (GridModule.problem() sets it).")
        key = (self.phi._version, self.phi.data_ptr(), self.corner_alpha.data_ptr())
        if self._cache is None or self._cache[0] != key:
            omega = grid_gradient(self.phi.detach(), grid_spacing(self.resolution)) + self.corner_alpha
            self._cache = (key, omega)
        return self._cache[1]

    def f(self, x: torch.Tensor) -> torch.Tensor:
        """Trilinear interpolation of φ. (P, 3) → (P,), differentiable in x."""
        # grid_sample reads its volume as (D, H, W) = (z, y, x) and its grid's last axis as (x, y, z);
        # align_corners=False puts sample i at −1 + (i + ½)h, the cell centres.
        return _trilinear(self.phi[None], x, align_corners=False)[:, 0]

    def alpha(self, x: torch.Tensor) -> torch.Tensor:
        """alpha_scale · α_Γ(x), closed form. (P, 3) → (P, 3)."""
        return self.alpha_scale * biot_savart(x, self.loops)

    def forward(self, x: torch.Tensor, create_graph: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
        """(f, ω) at points x: (P, 3) → ((P,), (P, 3)). ω interpolates the corners (align_corners=True)."""
        with torch.no_grad():
            return self.f(x), _trilinear(self.corner_current(), x, align_corners=True)

    @torch.no_grad()
    def evaluate(self, x: torch.Tensor, chunk_size: int = 1 << 15, omega: bool = True):
        """f (and ω) at many points in chunks. (P, 3) → (P,) [, (P, 3)]."""
        fs, ws = [], []
        for chunk in torch.split(x, chunk_size):
            if omega:
                f, w = self(chunk)
                ws.append(w)
            else:
                f = self.f(chunk)
            fs.append(f)
        return (torch.cat(fs), torch.cat(ws)) if omega else torch.cat(fs)


def _trilinear(volume: torch.Tensor, x: torch.Tensor, align_corners: bool) -> torch.Tensor:
    """Trilinear interpolation of a (C, n, n, n) volume (array axis i = coordinate i) over [-1, 1]³ at
    points (P, 3) → (P, C), in x's dtype; clamped past the outermost samples."""
    vol = volume.permute(0, 3, 2, 1)[None]  # grid_sample wants (1, C, z, y, x)
    grid = x.to(volume.dtype).reshape(1, 1, 1, -1, 3)
    out = F.grid_sample(vol, grid, mode="bilinear", padding_mode="border", align_corners=align_corners)
    return out.reshape(volume.shape[0], -1).T.to(x.dtype)


class ADMM(torch.optim.Optimizer):
    """The grid solver as a torch optimiser: each ``step()`` is one ADMM iteration on φ (the only param).

    Z, u, ρ and the iteration count are optimiser state, so Lightning checkpoints and resumes them.
    ``problem`` returns the GridProblem (α at the corners) on φ's device.
    """

    def __init__(self, phi: nn.Parameter, problem: Callable[[], GridProblem], rho: float,
                 relaxation: float = 1.6, balance: float = 10.0):
        super().__init__([phi], {"rho": rho, "relaxation": relaxation, "balance": balance})
        self.problem = problem
        self.last: ADMMReport | None = None

    @torch.no_grad()
    def step(self, closure=None):
        if closure is not None:
            closure()  # Lightning's hooks around a manual step
        group = self.param_groups[0]
        phi = group["params"][0]
        problem = self.problem()
        state = self.state[phi]
        if not state:
            state.update(z=problem.current(phi.data), u=torch.zeros_like(problem.alpha),
                         rho=float(group["rho"]), iteration=0)
        admm = ADMMState(phi.data, state["z"], state["u"], state["rho"], state["iteration"])
        self.last = admm_step(problem, admm, relaxation=group["relaxation"], balance=group["balance"])
        phi.data.copy_(admm.phi)
        state.update(z=admm.z, u=admm.u, rho=admm.rho, iteration=admm.iteration)
        return None
