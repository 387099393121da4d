"""Fourier features, the field MLP and the current: gradients, sizes, the paper's parameter count."""

import math

import numpy as np
import pytest
import torch

from deepcurrents.errors import ConfigError
from deepcurrents.geometry import biot_savart, circle, trefoil
from deepcurrents.losses import current_loss, surface_loss
from deepcurrents.nn import FieldMLP, FourierFeatures, neural_current


def paper_current(**kw):
    kw.setdefault("zero_init_output", False)  # a non-constant f, so that gradients are non-trivial
    return neural_current(3, loops=[torch.tensor(l, dtype=torch.float32) for l in trefoil()], **kw)


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


def test_coarse_to_fine_features_under_a_float64_default_dtype():
    """A user who sets torch's default dtype to float64 gets coarse-to-fine features in it (the ranks followed the
    default dtype while their values came in float32, and the constructor failed)."""
    old = torch.get_default_dtype()
    torch.set_default_dtype(torch.float64)
    try:
        ff = FourierFeatures(3, num_frequencies=16, seed=0, coarse_to_fine=0.5)
        ff.set_progress(0.1)
        weights = ff.feature_weights()
        assert weights.dtype == torch.float64 and 0.0 <= float(weights.min()) and float(weights.max()) <= 1.0
        assert 0.0 < float(weights.sum()) < 32.0  # some open, some still closed
    finally:
        torch.set_default_dtype(old)


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
    from conftest import validate_overrides

    assert isinstance(FieldMLP(4, 8, 2, "relu").net[1], torch.nn.ReLU)
    with pytest.raises(ConfigError, match="activation"):  # refused before anything is built
        validate_overrides(["experiment=minimal_trefoil", "model.net.activation=tanhh"])


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
    # winding cap: nothing up to one full jump J, linear beyond (a second turn of the phase along n)
    from deepcurrents.losses import winding_loss

    f_minus, f_plus = torch.tensor([0.01, 0.02, 0.05]), torch.tensor([0.0, 0.0, 0.01])
    assert winding_loss(f_minus, f_plus, 0.015).item() == pytest.approx((0.0 + 0.005 + 0.025) / 3)
    # level hinge: f(x) = −x_2 across the plane z = 0 (normal +z), ε = 0.02, reach 1/4 so f(y ∓ ε'n) = ±0.005; Γ's
    # points at f = 0.001 and 0.003, so s = 0.002: the inner side clears s + m (0.005 − 0.002 ≥ m = 0.001), the outer
    # side lies 0.007 below s; with m = 0.004 the inner side falls 0.001 short
    from deepcurrents.losses import level_loss

    batch = {"surface_points": torch.tensor([[0.3, 0.1, 0.0], [-0.2, 0.4, 0.0]]),
             "surface_normals": torch.tensor([[0.0, 0, 1], [0.0, 0, 1]]), "epsilon": torch.tensor([0.02, 0.02])}
    boundary = torch.tensor([[0.0, 0, -0.001], [1.0, 1, -0.003]])
    plane = lambda x: -x[:, 2:]  # noqa: E731
    assert level_loss(plane, batch, boundary, 0.001).item() == pytest.approx(0.0, abs=1e-9)
    assert level_loss(plane, batch, boundary, 0.004).item() == pytest.approx(0.001, rel=1e-4)
    # no jump at all (f constant) costs 2m, like the surface hinge's δ: never cheaper than a straddling drop
    assert level_loss(lambda x: 0 * x[:, :1] + 0.5, batch, boundary, 0.004).item() == pytest.approx(0.008, rel=1e-6)


def test_surface_hinge_of_a_batch_by_hand():
    """surface_hinge evaluates f at y ∓ εn: with f(x) = −c·z across the plane z = 0 (normal +z) the drop is
    2εc, so the hinge is (δ − 2εc)^+ per sample; a family's (S, M, 3) batch gives the mean over all S·M."""
    from deepcurrents.losses import surface_hinge

    y = torch.tensor([[0.1, 0.2, 0.0], [-0.3, 0.0, 0.0]])
    batch = {"surface_points": y, "surface_normals": torch.tensor([[0.0, 0.0, 1.0]] * 2),
             "epsilon": torch.tensor([0.02, 0.005])}
    for c in (0.1, 1.0):
        expected = (max(0.01 - 2 * 0.02 * c, 0.0) + max(0.01 - 2 * 0.005 * c, 0.0)) / 2
        assert surface_hinge(lambda p, c=c: -c * p[:, 2], batch, 0.01).item() == pytest.approx(expected)
    family = {key: torch.stack([value, value.flip(0)]) for key, value in batch.items()}
    assert surface_hinge(lambda p: -0.1 * p[..., 2], family, 0.01).item() == pytest.approx(
        (0.01 - 0.004 + 0.01 - 0.001) / 2)


def test_2d_current():
    model = neural_current(2, poles=torch.tensor([[-0.5, 0.0], [0.5, 0.0]]), signs=torch.tensor([-1.0, 1.0]),
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


@pytest.mark.parametrize("gradient", ["closed_form", "autograd"])
def test_closed_form_fourier_jacobian_gives_autograds_weight_gradients(gradient):
    """The training gradient (through ∇f) equals plain double-backward autograd through sin/cos, for both ways
    NeuralCurrent computes it (the hand-written pass and autograd to the features)."""
    torch.manual_seed(1)
    model = paper_current(num_frequencies=32, width=16, depth=2).double()
    model.gradient = gradient
    x = torch.rand(64, 3, dtype=torch.float64) * 2 - 1
    _, omega = model(x, create_graph=True)
    fast = torch.autograd.grad(current_loss(omega), list(model.mlp.parameters())[:-1])
    xr = x.clone().requires_grad_(True)
    (grad,) = torch.autograd.grad(model.f(xr).sum(), xr, create_graph=True)
    ref = torch.autograd.grad(current_loss(grad + model.alpha(x)), list(model.mlp.parameters())[:-1])
    for a, b in zip(fast, ref, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-10, atol=1e-12)


def _plain_autograd(model, x):
    """f and ∇f by autograd through the whole network, sin and cos included (the reference)."""
    xr = x.clone().requires_grad_(True)
    f = model.f(xr)
    (grad,) = torch.autograd.grad(f.sum(), xr, create_graph=True)
    return f, grad


def _relative_error(a, b):
    a = torch.zeros(()) if a is None else a  # autograd's None (no path) is a zero gradient
    b = torch.zeros(()) if b is None else b
    a, b = a.detach(), b.detach()
    return float((a - b).abs().max() / b.abs().max().clamp_min(1e-300)) if b.abs().max() > 0 else float(a.abs().max())


@pytest.mark.parametrize("activation", ["softplus", "relu"])
@pytest.mark.parametrize("rff", [True, False])
@pytest.mark.parametrize("dim", [3, 2])
def test_hand_written_gradient_network_matches_autograd(activation, rff, dim):
    """nn.field_gradient against autograd in float64: f, ∇f and every parameter's gradient of a loss that uses
    both (the current loss sees ∇f only; reconstruction's surface term sees f), to 1e-10 relative."""
    from deepcurrents.nn.field_gradient import closed_form_supported, field_and_gradient

    torch.manual_seed(3)
    if dim == 3:
        model = paper_current(num_frequencies=16, width=12, depth=3, activation=activation, rff=rff)
    else:
        model = neural_current(2, poles=torch.tensor([[-0.5, 0.0], [0.5, 0.0]]), signs=torch.tensor([-1.0, 1.0]),
                              num_frequencies=16, width=12, depth=3, activation=activation, rff=rff,
                              zero_init_output=False)
    model = model.double()
    assert closed_form_supported(model.mlp, model.encoding)
    x = torch.rand(50, dim, dtype=torch.float64) * 2 - 1
    f, grad = field_and_gradient(model.mlp, model.encoding, x)
    f_ref, grad_ref = _plain_autograd(model, x)
    # the same operations, but the pass keeps the features transposed, so its products may round differently
    assert _relative_error(f, f_ref.detach()) <= 1e-14
    assert grad.is_contiguous()  # (N, d) rows, whatever layout the pass keeps inside
    assert _relative_error(grad, grad_ref) <= 1e-10
    weights = torch.rand(50, dtype=torch.float64)
    params = list(model.mlp.parameters())
    for with_f in (False, True):
        def loss(f, grad, with_f=with_f):
            return current_loss(grad) + (weights * f).mean() if with_f else current_loss(grad)
        ours = torch.autograd.grad(loss(f, grad), params, retain_graph=True, allow_unused=True)
        ref = torch.autograd.grad(loss(f_ref, grad_ref), params, retain_graph=True, allow_unused=True)
        for name, a, b in zip([n for n, _ in model.mlp.named_parameters()], ours, ref, strict=True):
            assert _relative_error(a, b) <= 1e-10, (name, with_f)
        assert (ours[-1] is None) == (not with_f)  # the output's constant only matters through f


def test_hand_written_gradient_network_passes_gradcheck():
    """The hand-written backward against finite differences of its own forward (torch.autograd.gradcheck),
    with upstream gradients on both f and ∇f, including softplus's linear range above its threshold."""
    from deepcurrents.nn.field_gradient import _FieldGradient

    torch.manual_seed(4)
    model = paper_current(num_frequencies=4, width=5, depth=2).double()
    with torch.no_grad():
        model.mlp.net[2].bias[:2] = 25.0  # two units above softplus's threshold 20: σ' = 1, σ'' = 0 there
    x = torch.rand(7, 3, dtype=torch.float64) * 2 - 1
    params = tuple(p.detach().clone().requires_grad_(True) for p in model.mlp.parameters())

    def run(*params):
        return _FieldGradient.apply(x, model.encoding.frequencies, ("softplus", 1.0, 20.0), True, False, None, None,
                                    None, *params)

    assert torch.autograd.gradcheck(run, params, eps=1e-6, atol=1e-8, rtol=1e-6)


def test_hand_written_gradient_network_is_the_default_and_detaches_for_evaluation():
    model = paper_current(num_frequencies=16, width=8, depth=2)
    assert model.gradient == "closed_form"
    x = torch.rand(30, 3) * 2 - 1
    f, omega = model(x, create_graph=False)
    assert not f.requires_grad and not omega.requires_grad
    with torch.no_grad():
        f2, omega2 = model(x)
    torch.testing.assert_close(f, f2, rtol=0, atol=0)
    torch.testing.assert_close(omega, omega2, rtol=0, atol=0)
    torch.testing.assert_close(f, model.f(x))  # the same f, up to the rounding of the transposed features' products
    model.gradient = "autograd"
    f3, omega3 = model(x, create_graph=False)
    torch.testing.assert_close(omega, omega3, rtol=1e-5, atol=1e-6)  # float32: equal up to rounding


def test_medium_matmul_precision_trains_nearly_alike_and_evaluates_exactly():
    """model.net.matmul_precision=medium: the training pass's products get bf16 (CPU) internals where the
    hardware has them, so the loss's parameter gradients differ from IEEE fp32's by rounding only; evaluation
    passes are untouched, and the backend's setting is restored after the pass (so α's products stay IEEE)."""
    from deepcurrents.nn.field_gradient import reduced_precision_available

    torch.manual_seed(6)
    model = paper_current(num_frequencies=64, width=64, depth=3)
    x = torch.rand(512, 3) * 2 - 1
    before = torch.backends.mkldnn.matmul.fp32_precision

    def loss_grads(precision):
        model.matmul_precision = precision
        _, omega = model(x, create_graph=True)
        grads = torch.autograd.grad(current_loss(omega), list(model.mlp.parameters()), allow_unused=True)
        return torch.cat([g.flatten() for g in grads if g is not None])  # the output's constant: no gradient

    exact, medium = loss_grads("highest"), loss_grads("medium")
    assert torch.backends.mkldnn.matmul.fp32_precision == before  # restored after the forward and the backward
    difference = float((medium - exact).norm() / exact.norm())
    if reduced_precision_available("cpu"):
        assert 0.0 < difference < 0.05  # bf16 rounding (2^-9) inside fp32 products, not another computation
    else:
        assert difference == 0.0  # no bf16 hardware: the IEEE products
    for precision in ("highest", "medium"):  # evaluation: IEEE fp32 whatever the setting
        model.matmul_precision = precision
        f, omega = model(x, create_graph=False)
        if precision == "highest":
            reference = (f, omega)
        else:
            torch.testing.assert_close((f, omega), reference, rtol=0, atol=0)
    with pytest.raises(ConfigError, match=r"model\.net\.matmul_precision='low' must be one of highest, medium"):
        paper_current(num_frequencies=4, width=4, depth=1, matmul_precision="low")


@pytest.mark.parametrize("activation", ["softplus", "relu"])
def test_hand_written_gradient_network_with_a_code_per_shape(activation):
    """A decoder conditioned on a code per shape (the family's): the code's columns of the first layer folded
    into a bias per shape, against autograd through [code | φ(x)] in float64, gradients reaching the codes."""
    from deepcurrents.nn.field_gradient import closed_form_supported, field_and_gradient

    torch.manual_seed(5)
    shapes, n, code_dim = 3, 20, 4
    encoding = FourierFeatures(3, num_frequencies=8, seed=0).double()
    mlp = FieldMLP(code_dim + encoding.out_dim, 10, 2, activation).double()
    assert closed_form_supported(mlp, encoding, code_dim) and not closed_form_supported(mlp, encoding)
    code = torch.randn(shapes, code_dim, dtype=torch.float64, requires_grad=True)
    x = torch.rand(shapes, n, 3, dtype=torch.float64) * 2 - 1
    first = mlp.net[0]
    bias = torch.nn.functional.linear(code, first.weight[:, :code_dim], first.bias)
    f, grad = field_and_gradient(mlp, encoding, x, first_layer=(first.weight[:, code_dim:], bias))
    xr = x.clone().requires_grad_(True)
    f_ref = mlp(torch.cat([code[:, None].expand(-1, n, -1), encoding(xr)], -1)).squeeze(-1)
    (grad_ref,) = torch.autograd.grad(f_ref.sum(), xr, create_graph=True)
    assert f.shape == (shapes, n) and grad.shape == (shapes, n, 3)
    assert _relative_error(f, f_ref) <= 1e-12 and _relative_error(grad, grad_ref) <= 1e-10
    weights = torch.rand(shapes, n, dtype=torch.float64)
    wrt = [code, *mlp.parameters()]
    ours = torch.autograd.grad(current_loss(grad.reshape(-1, 3)) + (weights * f).mean(), wrt)
    ref = torch.autograd.grad(current_loss(grad_ref.reshape(-1, 3)) + (weights * f_ref).mean(), wrt)
    for a, b in zip(ours, ref, strict=True):
        assert _relative_error(a, b) <= 1e-10


@pytest.mark.parametrize("coarse_to_fine", [0.0, 0.5])
def test_family_decoder_takes_the_hand_written_pass_with_the_same_numbers(monkeypatch, coarse_to_fine):
    """FamilyCurrent.forward through nn.field_gradient against its autograd path in float64: f, ω and the
    gradients of every parameter (latent codes and boundary encoders included); also with coarse-to-fine
    features half open."""
    import deepcurrents.nn.family as family_module

    torch.manual_seed(6)
    fam = family_module.FamilyCurrent(num_shapes=3, num_loops=1, latent_dim=4, boundary_dim=4, num_frequencies=8,
                                      width=8, depth=2, zero_init_output=False,
                                      coarse_to_fine=coarse_to_fine).double()
    fam.encoding.set_progress(0.2)
    shapes, n = 2, 30
    loops = torch.tensor(circle(0.5, n=12))[None, None].expand(shapes, 1, -1, -1).contiguous()
    mask = torch.ones(shapes, 1, 12, dtype=torch.bool)
    x = torch.rand(shapes, n, 3, dtype=torch.float64) * 2 - 1
    weights = torch.rand(shapes, n, dtype=torch.float64)

    def run():
        code = fam.code(fam.latents(torch.arange(shapes)), loops, mask)
        f, omega = fam(x, code, loops, mask)
        grads = torch.autograd.grad(current_loss(omega.reshape(-1, 3)) + (weights * f).mean(), list(fam.parameters()))
        return f.detach(), omega.detach(), grads

    fast = run()
    monkeypatch.setattr(family_module, "closed_form_supported", lambda *args, **kwargs: False)
    ref = run()
    # (φ ⊙ w) W and φ (W ⊙ w) round differently, and so do the products of the pass's transposed features
    assert _relative_error(fast[0], ref[0]) <= 1e-12
    assert _relative_error(fast[1], ref[1]) <= 1e-12
    for a, b in zip(fast[2], ref[2], strict=True):
        assert _relative_error(a, b) <= 1e-10


def test_family_f_window_is_a_tanh_of_the_decoder_and_both_passes_agree(monkeypatch):
    """model.net.f_turns: f = W·tanh(h), W = f_turns·2π·alpha_scale, h the unwindowed decoder (the same weights with
    f_turns = 0); ∇f = W(1 − tanh²)∇h, the same through the hand-written pass and autograd (every parameter's
    gradient too); f stays inside ±W, and a zero-initialised window starts at f ≡ 0 (ω = α), its middle. A window
    of at most one jump is refused in one sentence."""
    import deepcurrents.nn.family as family_module

    def family(f_turns, zero_init_output=False):
        torch.manual_seed(7)
        return family_module.FamilyCurrent(num_shapes=2, num_loops=1, latent_dim=4, boundary_dim=4,
                                           num_frequencies=8, width=8, depth=2, zero_init_output=zero_init_output,
                                           alpha_scale=0.05, f_turns=f_turns).double()

    windowed, plain = family(1.5), family(0.0)
    w = 1.5 * 2 * math.pi * 0.05
    assert windowed.half_window == pytest.approx(w)
    loops = torch.tensor(circle(0.5, n=12))[None, None].expand(2, 1, -1, -1).contiguous()
    mask = torch.ones(2, 1, 12, dtype=torch.bool)
    x = torch.rand(2, 40, 3, dtype=torch.float64) * 2 - 1

    def run(fam):
        code = fam.code(fam.latents(torch.arange(2)), loops, mask)
        f, omega = fam(x, code, loops, mask)
        grads = torch.autograd.grad(current_loss(omega.reshape(-1, 3)) + f.square().mean(), list(fam.parameters()))
        return f.detach(), omega.detach(), grads

    f, omega, grads = run(windowed)
    h, omega_h, _ = run(plain)
    alpha = windowed.alpha(x, [[loops[0, 0]], [loops[1, 0]]])  # alpha_scale·α, the same for both
    t = torch.tanh(h)
    assert 0.2 < float(t.abs().max()) < 0.999  # the test reaches the tanh's bend, not only its linear part
    torch.testing.assert_close(f, w * t, rtol=1e-12, atol=1e-15)
    torch.testing.assert_close(omega - alpha, (w * (1 - t * t))[..., None] * (omega_h - alpha), rtol=1e-10,
                               atol=1e-15)
    start = family(1.5, zero_init_output=True)
    f0, omega0, _ = run(start)
    assert torch.equal(f0, torch.zeros_like(f0))
    torch.testing.assert_close(omega0, alpha, rtol=1e-12, atol=1e-15)
    with torch.no_grad():
        assert float(windowed.f(x, windowed.code(windowed.latents(torch.arange(2)), loops, mask)).abs().max()) < w
    monkeypatch.setattr(family_module, "closed_form_supported", lambda *args, **kwargs: False)
    ref = run(windowed)
    torch.testing.assert_close(ref[0], f, rtol=1e-12, atol=1e-15)
    assert _relative_error(ref[1], omega) <= 1e-12
    for a, b in zip(grads, ref[2], strict=True):
        assert _relative_error(a, b) <= 1e-10
    from conftest import validate_overrides

    # refused before anything is built
    with pytest.raises(ConfigError, match=r"model\.net\.f_turns=0\.9 must be 0 \(no window\) or above 1"):
        validate_overrides(["experiment=latent_hands", "model.net.f_turns=0.9"])
    with pytest.raises(ConfigError, match=r"model\.net\.f_turns=wide must be a non-negative number"):
        validate_overrides(["experiment=latent_hands", "model.net.f_turns=wide"])


def test_coarse_to_fine_features_open_in_order_of_frequency():
    """w_k ramps from 0 to 1 as the front passes rank(|B_k|); every w is 1 once the fraction coarse_to_fine of
    the budget is used, and then the features are the plain ones of the same seed."""
    ff = FourierFeatures(3, num_frequencies=200, sigma=2.0, seed=0, coarse_to_fine=0.5, coarse_start=0.25)
    plain = FourierFeatures(3, num_frequencies=200, sigma=2.0, seed=0)
    norms = ff.frequencies.norm(dim=1)
    order = torch.argsort(norms)
    ff.set_progress(0.0)
    w = ff.weights[order]  # by increasing |B_k|
    assert bool((w[1:] <= w[:-1]).all())  # lower frequencies are never less open
    assert int((w == 1).sum()) == 31 and int((w == 0).sum()) == 150  # ranks < 0.15 open, ≥ 0.25 closed
    x = torch.rand(7, 3) * 2 - 1
    sin, cos = ff.sin_cos(x)
    proj = 2 * math.pi * x @ ff.frequencies.T
    torch.testing.assert_close(sin, proj.sin() * ff.weights)
    torch.testing.assert_close(cos, proj.cos() * ff.weights)
    ff.set_progress(0.25)  # half way through the opening: front at 0.25 + 0.85/2 = 0.675
    assert int((ff.weights == 1).sum()) == 116 and int((ff.weights == 0).sum()) == 65  # ranks ≤ 0.575, ≥ 0.675
    for progress in (0.5, 0.9, 1.0):
        ff.set_progress(progress)
        assert bool((ff.weights == 1).all())
        torch.testing.assert_close(ff(x), plain(x))
    assert plain.weights is None and "weights" not in plain.state_dict()  # without it, checkpoints are as before
    assert "weights" in ff.state_dict()


@pytest.mark.parametrize("coarse_to_fine", [0.0, 0.5])
def test_coarse_to_fine_closed_form_matches_autograd(coarse_to_fine):
    """With half-open frequencies, nn.field_gradient (w folded into the first layer's columns) against autograd
    through the weighted features: f, ∇f and every parameter gradient in float64."""
    from deepcurrents.nn.field_gradient import field_and_gradient

    torch.manual_seed(7)
    model = paper_current(num_frequencies=16, width=12, depth=2, coarse_to_fine=coarse_to_fine).double()
    model.encoding.set_progress(0.2)
    if coarse_to_fine:
        assert 0 < float(model.encoding.weights.sum()) < 16
    x = torch.rand(40, 3, dtype=torch.float64) * 2 - 1
    f, grad = field_and_gradient(model.mlp, model.encoding, x)
    f_ref, grad_ref = _plain_autograd(model, x)
    assert _relative_error(f, f_ref) <= 1e-12 and _relative_error(grad, grad_ref) <= 1e-10
    params = list(model.mlp.parameters())
    ours = torch.autograd.grad(current_loss(grad), params, allow_unused=True)
    ref = torch.autograd.grad(current_loss(grad_ref), params, allow_unused=True)
    for a, b in zip(ours, ref, strict=True):
        assert _relative_error(a, b) <= 1e-10


# --- phase harmonics (model.net.phase_harmonics) ----------------------------------------------------------------


def harmonic_current(K=3, **kw):
    kw.setdefault("num_frequencies", 8)
    kw.setdefault("width", 16)
    kw.setdefault("depth", 2)
    return paper_current(phase_harmonics=K, **kw).double()


def test_phase_harmonics_gradient_is_the_gradient_of_f():
    """ω − α is ∇f, f = h·e(Ω/2) with the solid angle inside the basis: central differences of f itself."""
    torch.manual_seed(1)
    model = harmonic_current()
    x = torch.rand(40, 3, dtype=torch.float64) * 1.6 - 0.8
    _, omega = model(x, create_graph=False)
    eps = 1e-6
    fd = torch.stack([(model.f(x + eps * e) - model.f(x - eps * e)) / (2 * eps)
                      for e in torch.eye(3, dtype=torch.float64)], 1)
    grad_f = omega - model.alpha(x)
    assert fd.abs().max() > 0.1  # the harmonics' part (h·∂e/∂u)∇u is large next to Γ: not a trivial check
    assert (grad_f - fd).abs().max() < 1e-7


def test_phase_harmonics_f_is_continuous_across_the_solid_angles_branch_cut():
    """Ω jumps by 4π across its fan of triangles (centroid, v_i, v_i+1); f depends on u = Ω/2 only through
    integer harmonics, so it does not jump there."""
    from deepcurrents.geometry.biot_savart import solid_angle

    torch.manual_seed(2)
    model = harmonic_current()
    (loop,) = model.loops
    c = loop.mean(0)
    i = 7
    v0, v1 = loop[i], loop[i + 1]
    p = c + 0.3 * (v0 - c) + 0.3 * (v1 - c)  # inside fan triangle i
    n = torch.linalg.cross(v0 - c, v1 - c)
    n = n / n.norm()
    pts = torch.stack([p + 1e-9 * n, p - 1e-9 * n])
    jump = solid_angle(pts, model.loops)
    assert abs(abs(float(jump[0] - jump[1])) - 4 * math.pi) < 1e-6
    with torch.no_grad():
        f = model.f(pts)
    assert abs(float(f[0] - f[1])) < 1e-9


def test_phase_harmonics_closed_form_pass_matches_autograd():
    """The hand-written pass with an output basis against autograd: f, ω and every parameter gradient."""
    torch.manual_seed(3)
    model = harmonic_current(K=4)
    x = torch.rand(30, 3, dtype=torch.float64) * 2 - 1
    weights = torch.linspace(-1, 1, 30, dtype=torch.float64)

    def run(gradient):
        model.gradient = gradient
        f, omega = model(x, create_graph=True)
        loss = current_loss(omega) + (weights * f).mean()
        return f, omega, torch.autograd.grad(loss, list(model.mlp.parameters()))

    f, omega, ours = run("closed_form")
    f_ref, omega_ref, ref = run("autograd")
    assert _relative_error(f, f_ref) <= 1e-12 and _relative_error(omega, omega_ref) <= 1e-12
    for a, b in zip(ours, ref, strict=True):
        assert _relative_error(a, b) <= 1e-10


def test_phase_harmonics_reach_the_disk_with_constant_outputs():
    """The circle's minimal current is ω = 4π·a·n·δ_disk, f = −2a·saw(u) (u = Ω/2 ≡ π on the disk). Its truncated,
    Fejér-weighted series is constant outputs of the MLP (the output bias): its mass bound lands near the disk's
    area πR², while f ≡ const (ω = α, K = 0) is more than twice that. Mass by 2^16 uniform samples of [-1, 1]^3."""
    R, a = 0.5, 1e-3
    loops = [torch.tensor(circle(R, n=100))]
    gen = torch.Generator().manual_seed(5)
    x = torch.rand(1 << 16, 3, generator=gen, dtype=torch.float64) * 2 - 1

    def bound(K):
        model = neural_current(3, loops=loops, num_frequencies=4, width=4, depth=1, phase_harmonics=K).double()
        with torch.no_grad():
            model.mlp.net[-1].bias.zero_()
            for k in range(1, K + 1):  # saw(t) = 2 Σ (−1)^{k+1} sin(kt)/k, Fejér factors 1 − k/(K + 1)
                model.mlp.net[-1].bias[K + k] = 4.0 * (-1) ** k * (1 - k / (K + 1))
        norms = model(x, create_graph=False)[1].norm(dim=1)
        to_area = 8.0 / (4 * math.pi * a)
        return float(norms.mean()) * to_area, float(norms.std()) / math.sqrt(norms.numel()) * to_area

    disk = math.pi * R * R
    plain, _ = bound(0)
    sawtooth, err = bound(8)
    assert plain > 2.0 * disk
    assert disk - 4 * err < sawtooth < 1.2 * disk


def test_phase_harmonics_refuses_bad_values_in_one_sentence():
    from conftest import validate_overrides

    for bad in (-1, 2.5):  # refused before anything is built
        with pytest.raises(ConfigError, match="model.net.phase_harmonics"):
            validate_overrides(["experiment=minimal_trefoil", f"model.net.phase_harmonics={bad}"])
    with pytest.raises(ConfigError, match="3D boundary"):
        validate_overrides(["experiment=minimal_2d", "model.net.phase_harmonics=4"])
