"""The autodecoder's test-time step: the latent code of a shape the family was not trained on, by Adam on z alone
with the training losses (DeepSDF's test-time fit, paper §4.3)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch

from deepcurrents.data.family import collate_shapes
from deepcurrents.data.recon import ambient_options, ambient_sampler
from deepcurrents.data.targets import SURFACE_EPSILON, MeshTarget, target_sample
from deepcurrents.errors import number_at_least, positive_int

LATENT_FIT_DEFAULTS = {"steps": 300, "lr": 1e-2, "num_samples": 2000, "num_surface_samples": 2000, "prior_weight": 0.0}


def latent_fit_settings(latent_fit: dict | None) -> dict[str, Any]:
    """``model.latent_fit`` with its defaults filled in: the keyword arguments of ``fit_latent``'s settings."""
    return {**LATENT_FIT_DEFAULTS, **dict(latent_fit or {})}


def check_latent_fit(steps: Any, lr: Any, num_samples: Any, num_surface_samples: Any, prior_weight: Any) -> int:
    """One sentence naming the ``model.latent_fit`` setting that is wrong (ConfigError), else the step count."""
    positive_int("model.latent_fit.num_samples", num_samples)
    positive_int("model.latent_fit.num_surface_samples", num_surface_samples)
    number_at_least("model.latent_fit.lr", lr, strict=True)
    number_at_least("model.latent_fit.prior_weight", prior_weight)
    return positive_int("model.latent_fit.steps", steps)


def fit_latent(module: Any, vertices: np.ndarray, faces: np.ndarray, loops: Sequence[np.ndarray], steps: int = 300,
               lr: float = 1e-2, num_samples: int = 2000, num_surface_samples: int = 2000,
               boundary_sigma: float = 0.1, boundary_weighting: bool = True, seed: int = 0,
               metric_band: float | None = None, sampling: dict | None = None,
               surface_epsilon: float | tuple[float, float] = SURFACE_EPSILON,
               prior_weight: float = 0.0) -> tuple[torch.Tensor, list[float]]:
    """The latent code of a shape not trained on: Adam on z alone with ``module``'s training losses
    (``compute_losses``: current loss under B_x and surface loss on the unaugmented mesh, fresh samples every
    step); the decoder, the encoders and the training codes stay frozen. z starts at the mean training code μ.
    ``prior_weight`` w > 0 adds w·|z − μ|²/s², s² the training codes' mean squared distance from μ (a Gaussian
    prior on codes): the decoder has seen nothing far from its codes, and a code that wanders there can fit the
    losses with a wrong shape.

    module: an ``AutodecoderModule``. vertices (V, 3), faces (F, 3): the shape; loops: its B loops (M_b, 3) in the
    family's loop order. → (z (latent_dim,), the loss at each step (S,))."""
    steps = check_latent_fit(steps, lr, num_samples, num_surface_samples, prior_weight)
    prior_weight = float(prior_weight)
    loops = [np.asarray(lp, np.float64) for lp in loops]
    target = MeshTarget(vertices, faces, loops)
    ambient = ambient_sampler(target, ambient_options(sampling), seed=int(seed))
    gen = torch.Generator().manual_seed(int(seed))
    weight = module.family.latents.weight
    mean = weight.detach().mean(0, keepdim=True)  # (1, latent_dim)
    spread = float(((weight.detach() - mean) ** 2).sum(1).mean()) or 1.0  # s²; one training code: 1
    z = mean.clone().requires_grad_(True)
    opt = torch.optim.Adam([z], lr=float(lr))
    frozen = [(q, q.requires_grad) for q in module.family.parameters()]
    was_training, history = module.training, []
    try:
        for q, _ in frozen:
            q.requires_grad_(False)
        module.eval()  # the plain losses: no interpolation term
        with torch.enable_grad():
            for _ in range(steps):
                item = target_sample(target, num_samples, num_surface_samples, gen, boundary_sigma=boundary_sigma,
                                     boundary_weighting=boundary_weighting, surface_loss=True,
                                     metric_band=metric_band, ambient=ambient, surface_epsilon=surface_epsilon)
                item["index"], item["loops"] = 0, loops
                batch = {k: v.to(weight.device) for k, v in collate_shapes([item]).items()}
                loss = module.compute_losses(batch, z)["loss"]
                prior = prior_weight * ((z - mean) ** 2).sum() / spread if prior_weight > 0 else 0.0
                opt.zero_grad(set_to_none=True)
                (loss + prior).backward()
                opt.step()
                history.append(float(loss.detach()))  # the training losses alone, as without a prior
    finally:
        for q, flag in frozen:
            q.requires_grad_(flag)
        module.train(was_training)
    return z.detach()[0], history
