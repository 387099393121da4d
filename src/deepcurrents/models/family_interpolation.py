"""The interpolation regulariser of a family (beyond the paper): the Euclidean mass E_x|ω_t(x)| (B = I) of random
interpolants between the batch's shapes, latent codes and boundaries blended per pair, so that what lies between
training shapes is itself a near-minimal current (``model.interpolation_weight``; 0 = the paper)."""

from __future__ import annotations

import torch

from deepcurrents.data.sampling import NearTargetSampler
from deepcurrents.losses import current_loss
from deepcurrents.nn.family import FamilyCurrent

# how a pair's latent codes and boundaries are blended
INTERPOLATION_MIXES = ("shared", "independent")


class InterpolationRegulariser:
    """The interpolants' mass loss.

    ``mix``: "shared" (one t ~ U[0, 1] for code and boundary, the diagonal of an interpolation grid) or
    "independent" (t_z, t_Γ drawn apart: the code of one shape with the boundary of another, the grid's
    off-diagonal members). ``sampling`` (``data.recon.ambient_options``, without anchors): {"kind": "uniform"}
    (x ~ U) or "near": a share ``uniform_fraction`` uniform and the rest from Gaussians of σ = ``near_sigma``
    around the batch's surface samples of the pair's two shapes, with the importance weights 1/q that keep the
    loss an unbiased estimate of the mass (a shape fills a small part of U, where uniform points rarely fall)."""

    def __init__(self, mix: str, sampling: dict):
        self.mix, self.sampling = mix, sampling

    def loss(self, family: FamilyCurrent, z: torch.Tensor, loops: torch.Tensor, mask: torch.Tensor, num_points: int,
             surface_points: torch.Tensor | None = None) -> torch.Tensor | None:
        """E_x |ω_t(x)| of interpolants between each shape of the batch and the next one (a cyclic shift; batches
        come in random order, so every pair turns up): z_t = (1 − t) z_i + t z_j, Γ_s = (1 − s) Γ_i + s Γ_j vertex
        by vertex. Pairs whose loops differ in vertex counts are skipped (None if none is left).

        z (S, latent_dim), loops (S, B, L, 3), mask (S, B, L), surface_points (S, M, 3) → scalar."""
        other = torch.roll(torch.arange(len(z), device=z.device), -1)
        same = (mask == mask[other]).flatten(1).all(1) & (other != torch.arange(len(z), device=z.device))
        if not bool(same.any()):
            return None
        i, j = same.nonzero().squeeze(1), other[same]
        t = torch.rand(len(i), 1, device=z.device, dtype=z.dtype)
        s = torch.rand(len(i), 1, device=z.device, dtype=z.dtype) if self.mix == "independent" else t
        z_t = (1 - t) * z[i] + t * z[j]
        loops_t = (1 - s[:, :, None, None]) * loops[i] + s[:, :, None, None] * loops[j]
        code = family.code(z_t, loops_t, mask[i])
        x, weight = self.points(i, j, num_points, surface_points, loops.dtype)
        _, omega = family(x, code, loops_t, mask[i], create_graph=True)
        return current_loss(omega.flatten(0, 1), weight=None if weight is None else weight.flatten())

    def points(self, i: torch.Tensor, j: torch.Tensor, num_points: int, surface_points: torch.Tensor | None,
               dtype: torch.dtype) -> tuple[torch.Tensor, torch.Tensor | None]:
        """The loss's points for pairs (i, j) and their importance weights (None: uniform).

        → x (P, num_points, 3), weight (P, num_points) or None."""
        device = i.device
        sampling = self.sampling
        if sampling["kind"] == "uniform" or surface_points is None:
            return torch.rand(len(i), num_points, 3, device=device, dtype=dtype) * 2 - 1, None
        # NearTargetSampler per pair (numpy, on the CPU: a few thousand anchors), its stream seeded from torch's
        # so that runs stay reproducible under the run's seed
        anchors = torch.cat([surface_points[i], surface_points[j]], 1).detach().double().cpu().numpy()
        xs, weights = [], []
        for pair in anchors:
            sampler = NearTargetSampler(pair, float(sampling["near_sigma"]), float(sampling["uniform_fraction"]),
                                        weighted=bool(sampling["weighted"]))
            generator = torch.Generator().manual_seed(int(torch.randint(2**62, (1,))))
            x, w = sampler.sample(num_points, generator)
            xs.append(x)
            weights.append(w)
        return (torch.stack(xs).to(device=device, dtype=dtype),
                torch.stack(weights).to(device=device, dtype=dtype))
