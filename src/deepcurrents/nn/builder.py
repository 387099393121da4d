"""``neural_current``: a ``NeuralCurrent`` from the settings of ``model.net``, ``model.rff`` and
``model.grid_encoding`` (``models.base.network_kwargs``), its extensions chosen by them."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from deepcurrents.errors import ConfigError
from deepcurrents.nn.current import NeuralCurrent
from deepcurrents.nn.extensions.harmonics import PhaseHarmonics
from deepcurrents.nn.extensions.sharpening import PhaseSharpening
from deepcurrents.nn.field_gradient import check_matmul_precision
from deepcurrents.nn.fourier import FourierFeatures
from deepcurrents.nn.grid_encoding import MultiresGrid
from deepcurrents.nn.mlp import FieldMLP


def current_extensions(phase_harmonics: int = 0, phase_harmonics_start: float = 0.0,
                       phase_sharpening: float = 0.0, phase_sharpening_start: float = 0.0) -> list:
    """The extensions that ``model.net``'s settings choose (none: the paper's current); the settings are checked
    before anything is built (``experiments.schema``)."""
    extensions = []
    if phase_harmonics:
        extensions.append(PhaseHarmonics(phase_harmonics, phase_harmonics_start))
    if phase_sharpening:
        extensions.append(PhaseSharpening(phase_sharpening, phase_sharpening_start))
    return extensions


def neural_current(
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
) -> NeuralCurrent:
    """The current of Γ (3D: ``loops``, (M_i, 3) each; 2D: ``poles`` (P, 2) with ``signs`` (P,)) with the paper's
    network by default: ``num_frequencies`` Fourier frequencies of scale ``sigma`` (``rff=False``: x itself,
    ``coarse_to_fine``/``coarse_start``: ``FourierFeatures``), ``grid``: ``MultiresGrid`` keyword arguments for
    learned grid features after them (None: off), an MLP of ``depth`` × ``width`` units; the phase harmonics and
    sharpening (``current_extensions``).
    ``zero_init_output`` zeroes the last layer's weights, so f starts constant and ω as a·α (the authors' code
    uses PyTorch's default initialisation, False)."""
    if dim not in (2, 3):
        raise ConfigError(f"model.dim={dim} must be 2 or 3.")
    extensions = current_extensions(phase_harmonics, phase_harmonics_start, phase_sharpening, phase_sharpening_start)
    precision = check_matmul_precision(matmul_precision)
    if dim == 3 and not loops:
        raise ConfigError("A 3D current needs at least one boundary loop.")
    if dim == 2 and (poles is None or signs is None):
        raise ConfigError("A 2D current needs boundary points and their signs.")
    encoding = FourierFeatures(dim, num_frequencies, sigma, enabled=rff, seed=rff_seed,
                               coarse_to_fine=coarse_to_fine, coarse_start=coarse_start)
    grid_features = MultiresGrid(dim, seed=rff_seed, **grid) if grid else None
    mlp = FieldMLP(encoding.out_dim + (grid_features.out_dim if grid_features else 0), width, depth, activation,
                   out_dim=1 + sum(e.outputs for e in extensions))
    if zero_init_output:
        nn.init.zeros_(mlp.net[-1].weight)
        nn.init.zeros_(mlp.net[-1].bias[1:])  # the harmonics' coefficients too (none without them)
    return NeuralCurrent(encoding, mlp, loops, poles, signs, grid=grid_features, alpha_scale=alpha_scale,
                         matmul_precision=precision, extensions=extensions)
