"""Reconstruction's ambient samples concentrated near the target (data.sampling.kind=near): the weighted mean
is an unbiased estimate of the uniform mean over U = [-1, 1]^3 (checked against closed-form integrals), the
weights reach the metric, and bad settings stop with one sentence."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from conftest import spherical_cap
from scipy.special import erf

from deepcurrents.data.recon import ReconstructionDataModule, ambient_options, ambient_sampler
from deepcurrents.data.sampling import NearTargetSampler, truncated_gaussian_mass
from deepcurrents.data.targets import MeshTarget, target_sample
from deepcurrents.errors import ConfigError


def bump_mean(centre: np.ndarray, s: float) -> float:
    """E_{x~U([-1,1]^3)} exp(−|x − c|²/2s²), closed form (a product of erf differences)."""
    per_axis = [s * math.sqrt(math.pi / 2) * (erf((1 - c) / (s * math.sqrt(2))) + erf((1 + c) / (s * math.sqrt(2))))
                for c in centre]
    return float(np.prod(per_axis)) / 8.0


def sphere_anchors(n: int, radius: float, seed: int = 0) -> np.ndarray:
    a = np.random.default_rng(seed).normal(size=(n, 3))
    return radius * a / np.linalg.norm(a, axis=1, keepdims=True)


def weighted_means(sampler: NearTargetSampler, g, batches: int, n: int, seed: int) -> np.ndarray:
    gen = torch.Generator().manual_seed(seed)
    out = []
    for _ in range(batches):
        x, w = sampler.sample(n, gen)
        out.append(float((w * g(x)).mean()))
    return np.asarray(out)


def test_truncated_gaussian_mass_matches_monte_carlo():
    z = np.random.default_rng(0).normal(size=(400_000, 3))
    r = np.linalg.norm(z, axis=1)
    for radius in (1.0, 2.0, 3.0):
        assert truncated_gaussian_mass(radius) == pytest.approx((r <= radius).mean(), abs=3e-3)
    assert truncated_gaussian_mass(2.0, dim=2) == pytest.approx((np.linalg.norm(z[:, :2], axis=1) <= 2).mean(),
                                                                abs=3e-3)


@pytest.mark.parametrize("centre", [(0.3, 0.0, 0.2), (0.0, 0.0, 0.0)])
def test_weighted_mean_is_an_unbiased_estimate_of_a_known_integral(centre):
    """A sharp bump on the anchors' sphere (c on it) and one at its centre (no anchor near it: only the
    uniform share sees it) have closed-form means; the weighted estimate agrees within 4 standard errors,
    and for the bump on the target it is far less noisy than the same number of uniform samples."""
    centre = np.asarray(centre) * (0.36 / max(np.linalg.norm(centre), 1e-12) if np.any(centre) else 0.0)
    s = 0.05
    truth = bump_mean(centre, s)

    def g(x):
        return torch.exp(-((x - torch.as_tensor(centre)) ** 2).sum(1) / (2 * s * s))

    sampler = NearTargetSampler(sphere_anchors(1024, 0.36), sigma=0.03, uniform_fraction=0.5)
    est = weighted_means(sampler, g, 200, 256, seed=1)
    stderr = est.std() / math.sqrt(len(est))
    assert abs(est.mean() - truth) < 4 * stderr + 1e-12
    if np.any(centre):
        gen = torch.Generator().manual_seed(2)
        uniform = [float(g(torch.rand(256, 3, generator=gen, dtype=torch.float64) * 2 - 1).mean()) for _ in range(200)]
        assert est.std() < 0.5 * np.std(uniform)


def test_weights_have_mean_one_and_are_bounded_by_the_uniform_share():
    sampler = NearTargetSampler(sphere_anchors(2048, 0.3), sigma=0.02, uniform_fraction=0.25)
    _, w = sampler.sample(4096, torch.Generator().manual_seed(0))
    assert w.max() <= 1 / 0.25 + 1e-9
    # the first quarter is uniform: mostly far from the sphere, where w = 1/u exactly
    assert (w[:1024] == 4.0).float().mean() > 0.8
    means = weighted_means(sampler, lambda x: torch.ones(len(x), dtype=torch.float64), 100, 1024, seed=3)
    assert abs(means.mean() - 1.0) < 4 * means.std() / 10


def test_near_samples_outside_the_domain_get_weight_zero_and_the_estimate_stays_unbiased():
    """Anchors at a corner of U: about half of the near samples fall outside and weigh 0; a smooth
    integrand's mean (|x|², exactly 1 over U) is still estimated without bias."""
    anchors = np.full((64, 3), 0.99) + np.random.default_rng(0).normal(scale=0.005, size=(64, 3))
    sampler = NearTargetSampler(anchors, sigma=0.05, uniform_fraction=0.5)
    x, w = sampler.sample(2048, torch.Generator().manual_seed(0))
    outside = (x.abs() > 1).any(1)
    assert outside.any() and (w[outside] == 0).all() and (w[~outside] > 0).all()
    est = weighted_means(sampler, lambda x: (x**2).sum(1), 200, 256, seed=4)
    assert abs(est.mean() - 1.0) < 4 * est.std() / math.sqrt(len(est))


def test_unweighted_near_samples_weigh_one():
    sampler = NearTargetSampler(sphere_anchors(256, 0.3), sigma=0.02, uniform_fraction=0.5, weighted=False)
    x, w = sampler.sample(100, torch.Generator().manual_seed(0))
    assert x.shape == (100, 3) and torch.equal(w, torch.ones(100, dtype=torch.float64))
    # the second half lies near the anchors: within 3σ of the sphere of radius 0.3
    r = x[50:].norm(dim=1)
    assert ((r - 0.3).abs() <= 3 * 0.02 + 1e-9).all()


def test_importance_weights_reach_the_metric():
    """With the boundary weighting off, B_x = w_imp(x) (I − n nᵀ) exactly, w_imp the sampler's weight at x."""
    cap = spherical_cap(0.4, 0.2, subdivisions=3)
    target = MeshTarget(cap.vertices, cap.faces)
    sampler = ambient_sampler(target, ambient_options({"kind": "near", "near_sigma": 0.03, "anchors": 512}), seed=0)
    batch = target_sample(target, 300, 0, torch.Generator().manual_seed(0), boundary_weighting=False,
                          surface_loss=False, ambient=sampler)
    x = batch["x"].double().numpy()
    w = sampler.weight(x, 0.5)
    near = target.closest(x)
    n = np.where(near.on_boundary[:, None], 0.0, near.normal)
    expected = w[:, None, None] * (np.eye(3) - n[:, :, None] * n[:, None, :])
    # (x is float32 in the batch: a few points right at a fold or at Γ may pick another closest face)
    close = np.isclose(batch["metric"].numpy(), expected, rtol=1e-4, atol=1e-6).all((1, 2))
    assert close.mean() > 0.97
    # both kinds of sample are in the boundary-weighted first half (the batch is shuffled)
    assert 0.2 < (w[:150] < 2 - 1e-6).mean() < 0.8


def test_uniform_sampling_is_the_papers_batch():
    """kind=uniform (the default) draws exactly the batch of before (same generator, same x)."""
    cap = spherical_cap(0.4, 0.2, subdivisions=2)
    target = MeshTarget(cap.vertices, cap.faces)
    a = target_sample(target, 64, 8, torch.Generator().manual_seed(5))
    b = target_sample(target, 64, 8, torch.Generator().manual_seed(5),
                      ambient=ambient_sampler(target, ambient_options(None)))
    for key in a:
        assert torch.equal(a[key], b[key])


@pytest.mark.parametrize(("sampling", "words"), [
    ({"kind": "sobol"}, "data.sampling.kind='sobol'"),
    ({"kind": "near", "near_sigma": 0}, "data.sampling.near_sigma=0"),
    ({"kind": "near", "uniform_fraction": 1.5}, "data.sampling.uniform_fraction=1.5"),
    ({"kind": "near", "anchors": 0}, "data.sampling.anchors"),
    ({"kind": "near", "pool": 4}, "unknown keys ['pool']"),
])
def test_bad_sampling_settings_are_one_sentence(tmp_path, sampling, words):
    cap = spherical_cap(0.4, 0.2, subdivisions=1)
    path = tmp_path / "cap.ply"
    cap.export(path)
    with pytest.raises(ConfigError) as err:
        ReconstructionDataModule(mesh=str(path), sampling=sampling)
    assert words in str(err.value)
