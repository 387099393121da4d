"""The von Mises map of the circle (geometry.phase_map) and the phase sharpening it gives NeuralCurrent, against
quadrature, finite differences and the coarea formula: ψ' has mean 1 over a turn, ψ' is the derivative of ψ,
ψ(φ + 2π) = ψ(φ) + 2π; the sharpened current is ψ'(φ)·ω with f single valued, and its ω is ∇f + alpha_scale·α."""

import math

import numpy as np
import pytest
import torch

from deepcurrents.errors import ConfigError
from deepcurrents.geometry import circle
from deepcurrents.geometry.biot_savart import solid_angle
from deepcurrents.geometry.phase_map import von_mises_offset, von_mises_slope
from deepcurrents.nn import NeuralCurrent, neural_current
from deepcurrents.nn.extensions import RAMP


@pytest.mark.parametrize("kappa", [0.5, 4.0, 30.0])
def test_von_mises_slope_has_mean_one_over_a_turn(kappa):
    phase = torch.linspace(0.0, 2.0 * math.pi, 20001, dtype=torch.float64)[:-1]
    assert float(von_mises_slope(phase, 1.3, kappa).mean()) == pytest.approx(1.0, rel=1e-9)


@pytest.mark.parametrize("kappa", [0.0, 1.0, 16.0])
def test_von_mises_map_is_a_degree_one_map_with_that_slope(kappa):
    phase = torch.linspace(-7.0, 7.0, 2001, dtype=torch.float64)
    psi = phase + von_mises_offset(phase, 0.4, kappa)
    turned = phase + 2.0 * math.pi
    assert torch.allclose(turned + von_mises_offset(turned, 0.4, kappa), psi + 2.0 * math.pi, atol=1e-9)
    h = 1e-5  # central differences of ψ against ψ'
    fd = (von_mises_offset(phase + h, 0.4, kappa) - von_mises_offset(phase - h, 0.4, kappa)) / (2 * h) + 1.0
    assert torch.allclose(fd, von_mises_slope(phase, 0.4, kappa), rtol=1e-6, atol=1e-7)
    assert bool((torch.diff(psi) > -1e-9).all())  # monotone (up to the series kept: terms ≥ 1e-10)


def test_von_mises_offset_first_met_in_inference_mode_still_trains():
    """Its terms are kept per κ: a first call from an evaluation under ``torch.inference_mode`` must not leave
    inference tensors that a later training step cannot save for its backward; the same values either way."""
    kappa = 1.2345  # a κ no other test uses, so this call makes its terms
    phase = torch.linspace(-3.0, 3.0, 17, dtype=torch.float64)
    with torch.inference_mode():
        evaluated = von_mises_offset(phase, 0.4, kappa)
    trained = phase.clone().requires_grad_(True)
    offset = von_mises_offset(trained, 0.4, kappa)
    offset.sum().backward()
    assert torch.equal(offset.detach(), evaluated)
    assert torch.allclose(trained.grad, von_mises_slope(phase, 0.4, kappa) - 1.0, atol=1e-9)


def _current(**kwargs) -> NeuralCurrent:
    torch.manual_seed(0)
    loop = torch.tensor(circle(0.5, n=64)).double()
    current = neural_current(3, loops=[loop], num_frequencies=8, width=16, depth=2, zero_init_output=False,
                            **kwargs).double()
    return current


def test_sharpened_current_is_the_network_current_times_psi_prime():
    plain, sharp = _current(), _current(phase_sharpening=4.0)
    x = torch.rand(300, 3, dtype=torch.float64) * 2 - 1
    f0, w0 = plain(x, create_graph=False)
    f1, w1 = sharp(x, create_graph=False)
    bias = float(plain.mlp.net[-1].bias[0])  # φ without f_θ's output bias (nn.extensions.sharpening)
    phase = (f0 - bias) / (2 * plain.alpha_scale) + 0.5 * solid_angle(x, plain.loops)
    level = float(sharp.sharpening_level)
    probes = torch.quasirandom.SobolEngine(3, scramble=True, seed=0).draw(4096).double() * 2 - 1
    f_probes = plain.f(probes) - bias
    probe_phase = f_probes / (2 * plain.alpha_scale) + 0.5 * solid_angle(probes, plain.loops)
    theta = math.atan2(float(torch.sin(probe_phase).mean()), float(torch.cos(probe_phase).mean()))
    assert level == pytest.approx(theta + math.pi)  # opened on fixed points: c = θ + π
    assert torch.allclose(w1, von_mises_slope(phase, level, 4.0)[:, None] * w0, rtol=1e-10)
    assert torch.allclose(f1, f0 + 2 * plain.alpha_scale * von_mises_offset(phase, level, 4.0), rtol=1e-10)
    assert torch.allclose(sharp.f(x), f1, rtol=1e-10)  # the no-ω path agrees


def test_sharpened_omega_is_grad_f_plus_alpha():
    """ω = ∇f + alpha_scale·α for the sharpened f, by central differences away from Γ and the cut of Ω."""
    sharp = _current(phase_sharpening=8.0)
    x = torch.tensor([[0.3, 0.1, 0.4], [-0.2, 0.6, -0.3], [0.8, -0.7, 0.2]], dtype=torch.float64)
    sharp(torch.rand(200, 3, dtype=torch.float64) * 2 - 1, create_graph=False)  # opens: sets the level
    _, omega = sharp(x, create_graph=False)
    h = 1e-7  # φ = f/(2·alpha_scale) + Ω/2 turns fast: the differences' O(h²) error is 2e-7 at h = 1e-6
    steps = torch.eye(3, dtype=torch.float64) * h
    fd = torch.stack([(sharp.f(x + e) - sharp.f(x - e)) / (2 * h) for e in steps], 1)
    assert torch.allclose(omega, fd + sharp.alpha(x), rtol=1e-5, atol=1e-8)


def test_sharpening_trains_through_f_and_omega():
    """The loss's parameter gradient through ψ'(φ) (which depends on f) matches finite differences."""
    sharp = _current(phase_sharpening=2.0)
    x = torch.rand(64, 3, dtype=torch.float64) * 2 - 1
    sharp(x, create_graph=False)
    weight = sharp.mlp.net[0].weight

    def loss():
        return sharp(x)[1].norm(dim=-1).mean()

    (grad,) = torch.autograd.grad(loss(), weight)
    h, (i, j) = 1e-6, (3, 5)
    with torch.no_grad():
        weight[i, j] += h
        up = float(loss())
        weight[i, j] -= 2 * h
        down = float(loss())
        weight[i, j] += h
    assert float(grad[i, j]) == pytest.approx((up - down) / (2 * h), rel=1e-5, abs=1e-10)


def test_sharpening_opens_with_the_budget():
    sharp = _current(phase_sharpening=8.0, phase_sharpening_start=0.5)
    assert sharp.follows_progress and float(sharp.sharpening) == 0.0
    sharp.set_progress(0.6)
    assert float(sharp.sharpening) == pytest.approx(8.0 * 0.1 / RAMP)
    sharp.set_progress(0.95)
    assert float(sharp.sharpening) == 8.0


def test_sharpened_2d_current_is_grad_f_plus_alpha():
    """In 2D the phase is f/alpha_scale + Σ s_j·angle(x − p_j): ω = ∇f + alpha_scale·α by central differences."""
    torch.manual_seed(1)
    sharp = neural_current(2, poles=torch.tensor([[-0.4, 0.0], [0.4, 0.1]]), signs=torch.tensor([-1.0, 1.0]),
                          num_frequencies=8, width=16, depth=2, zero_init_output=False, phase_sharpening=4.0).double()
    sharp(torch.rand(200, 2, dtype=torch.float64) * 2 - 1, create_graph=False)
    x = torch.tensor([[0.1, 0.5], [-0.6, -0.3], [0.7, -0.8]], dtype=torch.float64)
    _, omega = sharp(x, create_graph=False)
    h = 1e-7
    fd = torch.stack([(sharp.f(x + e) - sharp.f(x - e)) / (2 * h) for e in torch.eye(2, dtype=torch.float64) * h], 1)
    assert torch.allclose(omega, fd + sharp.alpha(x), rtol=1e-5, atol=1e-8)


def test_output_bias_gets_no_gradient_from_the_sharpening():
    """φ is taken without f_θ's output bias (a constant turn of every level): the loss does not move it."""
    sharp = _current(phase_sharpening=4.0)
    x = torch.rand(128, 3, dtype=torch.float64) * 2 - 1
    loss = sharp(x)[1].norm(dim=-1).mean()
    (grad,) = torch.autograd.grad(loss, sharp.mlp.net[-1].bias)
    assert float(grad.abs().max()) == 0.0


@pytest.mark.parametrize("kwargs, words", [({"phase_sharpening": -1.0}, "κ ≥ 0"),
                                           ({"phase_sharpening": "two"}, "κ ≥ 0"),
                                           ({"phase_sharpening": 2.0, "phase_sharpening_start": 1.0}, "fraction"),
                                           ({"phase_sharpening": 2.0, "phase_sharpening_start": "half"}, "fraction")])
def test_bad_sharpening_values_are_refused(kwargs, words):
    from conftest import validate_overrides

    overrides = [f"model.net.{key}={value}" for key, value in kwargs.items()]
    with pytest.raises(ConfigError, match=words):  # refused before anything is built
        validate_overrides(["experiment=minimal_trefoil", *overrides])


def test_meshers_read_a_sharpened_current_through_its_network_phase():
    """ψ is monotone, so the level sets are the network's: the mesh and the certificate read φ itself (smooth),
    and the context gives κ back afterwards."""
    from deepcurrents.eval.level_sets import level_set_view
    from deepcurrents.eval.meshing import extract_surface

    torch.manual_seed(0)
    loop = torch.tensor(circle(0.5, n=64)).float()
    sharp = neural_current(3, loops=[loop], num_frequencies=8, width=8, depth=1, phase_sharpening=8.0)
    sharp(torch.rand(64, 3) * 2 - 1, create_graph=False)  # opens
    with level_set_view(sharp):
        assert float(sharp.sharpening) == 0.0
        plain = extract_surface(sharp, resolution=32)
    assert float(sharp.sharpening) == 8.0
    meshed = extract_surface(sharp, resolution=32)
    assert float(sharp.sharpening) == 8.0
    assert meshed.mesh.area == pytest.approx(plain.mesh.area, rel=1e-12)
    assert meshed.mesh.area == pytest.approx(math.pi * 0.25, rel=0.02)  # f_θ ≡ const: the flat disk


def test_harmonics_opening_first_leave_the_sharpening_closed():
    """With harmonics open and the sharpening not yet, the current is the harmonics' and c stays unset."""
    both = _current(phase_harmonics=2, phase_sharpening=2.0, phase_sharpening_start=0.5)
    x = torch.rand(32, 3, dtype=torch.float64) * 2 - 1
    both(x, create_graph=False)
    assert math.isnan(float(both.sharpening_level))
    both.set_progress(0.9)
    both(x, create_graph=False)
    assert math.isfinite(float(both.sharpening_level))


def test_loaded_checkpoint_carries_the_opened_harmonics_and_sharpening():
    """The forward reads Python copies of the gate, κ and whether c is set (no device read per step on a GPU):
    a state loaded into a fresh current must bring them along, so that it computes what the saved one did."""
    trained = _current(phase_harmonics=2, phase_harmonics_start=0.5, phase_sharpening=3.0,
                       phase_sharpening_start=0.5)
    x = torch.rand(64, 3, dtype=torch.float64) * 2 - 1
    trained.set_progress(0.6)  # gate and κ half open (ramp 0.2)
    f_trained, w_trained = trained(x, create_graph=False)  # opens c
    fresh = _current(phase_harmonics=2, phase_harmonics_start=0.5, phase_sharpening=3.0,
                     phase_sharpening_start=0.5)
    f_closed, _ = fresh(x, create_graph=False)
    assert not torch.allclose(f_closed, f_trained)  # closed: not the trained current
    fresh.load_state_dict(trained.state_dict())
    assert float(fresh.sharpening_level) == float(trained.sharpening_level)
    f_loaded, w_loaded = fresh(x, create_graph=False)
    assert torch.equal(f_loaded, f_trained) and torch.equal(w_loaded, w_trained)
    with trained.level_set_view():
        w_network = trained(x, create_graph=False)[1]
    assert not torch.allclose(w_network, w_trained)
    with fresh.level_set_view():  # and the copies follow the buffers through the context
        assert float(fresh.sharpening) == 0.0
        assert torch.equal(fresh(x, create_graph=False)[1], w_network)
    assert float(fresh.sharpening) == float(trained.sharpening) == pytest.approx(3.0 * 0.5)


def test_the_2d_curve_extractor_reads_a_sharpened_current_through_its_network_phase():
    """extract_curve_2d runs inside level_set_view and without autograd, as the 3D meshers: a sharpened 2D current
    gives the curve of its network's phase (a review found the decorators moved onto a helper: the sharpened
    current's phase curve vanished)."""
    from deepcurrents.eval.level_sets import level_set_view
    from deepcurrents.eval.meshing import extract_curve_2d

    torch.manual_seed(0)
    sharp = neural_current(2, poles=torch.tensor([[-0.5, 0.0], [0.5, 0.0]]), signs=torch.tensor([-1.0, 1.0]),
                          num_frequencies=8, width=8, depth=1, phase_sharpening=8.0)
    sharp(torch.rand(64, 2) * 2 - 1, create_graph=False)  # opens
    grad_modes = []
    real_evaluate = sharp.evaluate

    def evaluate(*args, **kwargs):
        grad_modes.append(torch.is_grad_enabled())
        return real_evaluate(*args, **kwargs)

    sharp.evaluate = evaluate
    with level_set_view(sharp):
        plain = extract_curve_2d(sharp, resolution=63, delta=0.0)
    curves = extract_curve_2d(sharp, resolution=63, delta=0.0)
    assert float(sharp.sharpening) == 8.0 and len(curves) == len(plain) == 1
    assert np.array_equal(curves[0], plain[0])
    assert grad_modes and not any(grad_modes)
