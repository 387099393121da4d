"""Fourier features, the field MLP and the current: gradients, sizes, the paper's parameter count."""

import math

import numpy as np
import pytest
import torch

from deepcurrents.errors import ConfigError
from deepcurrents.geometry import biot_savart, circle, trefoil
from deepcurrents.losses import current_loss, surface_loss
from deepcurrents.nn import FieldMLP, FourierFeatures, NeuralCurrent


def paper_current(**kw):
    kw.setdefault("zero_init_output", False)  # a non-constant f, so that gradients are non-trivial
    return NeuralCurrent(3, loops=[torch.tensor(l, dtype=torch.float32) for l in trefoil()], **kw)


def test_zero_initialised_output_starts_from_alpha():
    model = paper_current(num_frequencies=16, width=16, depth=2, zero_init_output=True)
    x = torch.rand(20, 3) * 2 - 1
    f, omega = model(x, create_graph=False)
    torch.testing.assert_close(omega, model.alpha(x))
    assert torch.allclose(f, f[0].expand_as(f))


def test_paper_network_parameter_count():
    model = paper_current()
    trainable = sum(p.numel() for p in model.parameters() if p.requires_grad)
    assert trainable == 722_177
    assert model.encoding.frequencies.numel() == 3072  # 725,249 with the frozen frequencies (paper)
    assert trainable + model.encoding.frequencies.numel() == 725_249


def test_fourier_features_values_and_frozen():
    ff = FourierFeatures(3, num_frequencies=4, sigma=2.0, seed=0)
    x = torch.randn(5, 3)
    proj = 2 * math.pi * x @ ff.frequencies.T
    torch.testing.assert_close(ff(x), torch.cat([proj.sin(), proj.cos()], -1))
    assert list(ff.parameters()) == [] and ff.out_dim == 8
    off = FourierFeatures(3, enabled=False)
    assert off(x) is x and off.out_dim == 3
    # frequencies ~ N(0, σ²)
    big = FourierFeatures(3, num_frequencies=20000, sigma=2.0, seed=1).frequencies
    assert abs(big.std().item() - 2.0) < 0.03


def test_gradient_matches_finite_differences():
    model = paper_current(num_frequencies=64, width=32, depth=2).double()
    x = torch.rand(6, 3, dtype=torch.float64) * 1.6 - 0.8
    f, omega = model(x, create_graph=False)
    grad = omega - model.alpha(x)
    h = 1e-6
    for j in range(3):
        e = torch.zeros(3, dtype=torch.float64)
        e[j] = h
        fd = (model.f(x + e) - model.f(x - e)) / (2 * h)
        torch.testing.assert_close(grad[:, j], fd.detach(), rtol=1e-6, atol=1e-8)
    torch.testing.assert_close(model.alpha(x), 1e-3 * biot_savart(x, model.loops))


def test_double_backward_reaches_the_weights():
    model = paper_current(num_frequencies=16, width=16, depth=2)
    _, omega = model(torch.rand(32, 3) * 2 - 1, create_graph=True)
    current_loss(omega).backward()
    *weights, out_bias = list(model.mlp.parameters())
    assert all(p.grad is not None and torch.isfinite(p.grad).all() for p in weights)
    assert out_bias.grad is None  # ω sees f only through ∇f: the output's constant does not matter
    # the first layer's bias only enters f through ∇f via the activations' curvature: its grad is non-zero
    assert model.mlp.net[0].bias.grad.abs().sum() > 0


def test_evaluate_in_chunks_matches_forward():
    model = paper_current(num_frequencies=16, width=16, depth=2)
    x = torch.rand(100, 3) * 2 - 1
    f, w = model.evaluate(x, chunk_size=7)
    f2, w2 = model(x, create_graph=False)
    torch.testing.assert_close(f, f2)
    torch.testing.assert_close(w, w2)


def test_relu_and_bad_activation():
    assert isinstance(FieldMLP(4, 8, 2, "relu").net[1], torch.nn.ReLU)
    with pytest.raises(ConfigError, match="activation"):
        FieldMLP(4, 8, 2, "tanhh")


def test_losses_by_hand():
    omega = torch.tensor([[3.0, 4.0, 0.0], [0.0, 0.0, 1.0]])
    assert current_loss(omega).item() == pytest.approx(3.0)
    n = torch.tensor([0.0, 0.0, 1.0])
    proj = torch.eye(3) - torch.outer(n, n)
    metric = torch.stack([2 * proj, proj])
    assert current_loss(omega, metric).item() == pytest.approx((10.0 + 0.0) / 2)
    assert current_loss(omega, torch.tensor([0.5, 2.0])).item() == pytest.approx((2.5 + 2.0) / 2)
    # hinge: satisfied when f drops by ≥ δ across the surface along n, linear otherwise
    assert surface_loss(torch.tensor([0.02]), torch.tensor([0.0]), 0.01).item() == 0.0
    assert surface_loss(torch.tensor([0.0]), torch.tensor([0.0]), 0.01).item() == pytest.approx(0.01)
    assert surface_loss(torch.tensor([0.0]), torch.tensor([0.03]), 0.01).item() == pytest.approx(0.04)


def test_2d_current():
    model = NeuralCurrent(2, poles=torch.tensor([[-0.5, 0.0], [0.5, 0.0]]), signs=torch.tensor([-1.0, 1.0]),
                          num_frequencies=8, width=8, depth=1)
    f, w = model(torch.rand(10, 2) * 2 - 1, create_graph=False)
    assert f.shape == (10,) and w.shape == (10, 2)


def test_circle_mass_bound_of_the_exact_current():
    """∫|ω| of ω = ∇f + α with f = −Ω·alpha_scale (cut on the disk) is 4π·alpha_scale·area: check the
    normalisation of mass_to_area on the analytic optimum, via the jump of the solid angle across the disk."""
    from deepcurrents.eval.metrics import mass_to_area
    from deepcurrents.geometry import solid_angle

    loop = torch.tensor(circle(0.6, n=400))
    eps = 1e-4
    inside = torch.tensor([[0.1, 0.2, eps], [0.1, 0.2, -eps]], dtype=torch.float64)
    jump = solid_angle(inside, [loop])
    assert (jump[0] - jump[1]).item() == pytest.approx(4 * math.pi, abs=1e-2)
    # the optimal current has mass 4π·a·Area; mass_to_area must return the area from E|ω| = mass / vol(U)
    area = math.pi * 0.36
    assert mass_to_area(4 * math.pi * 1e-3 * area / 8.0, 3, 1e-3) == pytest.approx(area)
    assert np.isclose(mass_to_area(2 * math.pi * 1e-3 * 1.0 / 4.0, 2, 1e-3), 1.0)


def test_closed_form_fourier_jacobian_gives_autograds_weight_gradients():
    """The training gradient (through ∇f) equals plain double-backward autograd through sin/cos."""
    torch.manual_seed(1)
    model = paper_current(num_frequencies=32, width=16, depth=2).double()
    x = torch.rand(64, 3, dtype=torch.float64) * 2 - 1
    _, omega = model(x, create_graph=True)
    fast = torch.autograd.grad(current_loss(omega), list(model.mlp.parameters())[:-1])
    xr = x.clone().requires_grad_(True)
    (grad,) = torch.autograd.grad(model.f(xr).sum(), xr, create_graph=True)
    ref = torch.autograd.grad(current_loss(grad + model.alpha(x)), list(model.mlp.parameters())[:-1])
    for a, b in zip(fast, ref, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-10, atol=1e-12)
