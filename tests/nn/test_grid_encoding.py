"""The multiresolution grid encoding: exact values at grid vertices, ∇_x by finite differences, and the double
backward the mass loss needs (∂/∂table of a function of ∇_x features) by gradcheck, dense and hashed levels."""

import pytest
import torch

from deepcurrents.errors import ConfigError
from deepcurrents.nn.grid_encoding import MultiresGrid


def grid(table_size: int = 1 << 18) -> MultiresGrid:
    return MultiresGrid(3, levels=3, base_resolution=2, finest_resolution=7, features=2, table_size=table_size,
                        init_scale=1.0, seed=0).double()


def test_resolutions_grow_geometrically_and_big_levels_are_hashed():
    g = grid(table_size=50)
    assert g.resolutions.tolist() == [2, 3, 7]
    assert g.hashed.tolist() == [False, True, True]      # 27 vertices fit in 50; 64 and 512 do not
    assert g.table.shape == (27 + 50 + 50, 2)
    assert g.out_dim == 6


def test_value_at_a_grid_vertex_is_that_vertex_row():
    g = grid()
    # the vertex (i, j, k) = (1, 0, 2) of the coarsest level (resolution 2) sits at x = -1 + 2·(i, j, k)/2
    x = torch.tensor([[0.0, -1.0, 1.0]], dtype=torch.float64)
    row = 1 + 3 * (0 + 3 * 2)                             # row-major with x fastest: i + 3(j + 3k)
    assert torch.allclose(g(x)[0, :2], g.table[row])


def test_linear_along_an_edge_between_vertices():
    g = grid()
    a = torch.tensor([[0.0, -1.0, 1.0]], dtype=torch.float64)
    b = torch.tensor([[1.0, -1.0, 1.0]], dtype=torch.float64)   # the next vertex along x on level 0
    mid = g((a + b) / 2)[0, :2]
    assert torch.allclose(mid, (g(a)[0, :2] + g(b)[0, :2]) / 2)


@pytest.mark.parametrize("table_size", [1 << 18, 50])
def test_input_gradient_matches_finite_differences(table_size):
    g = grid(table_size)
    x = torch.rand(6, 3, generator=torch.Generator().manual_seed(1), dtype=torch.float64) * 1.8 - 0.9
    jac = torch.autograd.functional.jacobian(g, x)        # (6, 6, 6, 3)
    h = 1e-6
    for d in range(3):
        e = torch.zeros_like(x)
        e[:, d] = h
        fd = (g(x + e) - g(x - e)) / (2 * h)
        analytic = torch.stack([jac[i, :, i, d] for i in range(len(x))])
        assert torch.allclose(fd, analytic, atol=1e-7)


@pytest.mark.parametrize("table_size", [1 << 18, 50])
def test_double_backward_through_the_input_gradient(table_size):
    g = grid(table_size)
    x = torch.rand(5, 3, generator=torch.Generator().manual_seed(2), dtype=torch.float64) * 1.8 - 0.9
    mix = torch.arange(1.0, 7.0, dtype=torch.float64)

    def grad_norm(table):
        xg = x.clone().requires_grad_(True)
        out = torch.func.functional_call(g, {"table": table}, (xg,))
        (gx,) = torch.autograd.grad((out * mix).sum(), xg, create_graph=True)
        return gx.norm(dim=-1)

    assert torch.autograd.gradcheck(grad_norm, (g.table.detach().clone().requires_grad_(True),))


def test_impossible_sizes_are_refused_in_one_sentence():
    with pytest.raises(ConfigError, match="finest_resolution"):
        MultiresGrid(3, base_resolution=16, finest_resolution=8)
    with pytest.raises(ConfigError, match="levels"):
        MultiresGrid(3, levels=0)
    from conftest import validate_overrides

    from deepcurrents.models.base import network_kwargs

    for bad in (-1, 2.5, "true"):  # a negative level count used to switch the grid off silently
        with pytest.raises(ConfigError, match="model.grid_encoding.levels"):
            validate_overrides(["experiment=minimal_trefoil", f"model.grid_encoding.levels={bad}"])
    assert "grid" not in network_kwargs({"width": 8, "depth": 1}, None, {"levels": 0})


def test_current_with_grid_features_has_omega_equal_to_grad_f_plus_alpha():
    """NeuralCurrent with grid features: ω − alpha_scale·α is ∇f by central differences (float64), and the
    training backward reaches the grid table."""
    from deepcurrents.geometry import circle
    from deepcurrents.nn import neural_current

    torch.manual_seed(0)
    current = neural_current(3, loops=[torch.tensor(circle(0.5, n=32))], num_frequencies=8, width=16, depth=2,
                            zero_init_output=False, rff_seed=0,
                            grid={"levels": 2, "base_resolution": 2, "finest_resolution": 5, "init_scale": 0.5})
    current = current.double()
    x = torch.rand(7, 3, generator=torch.Generator().manual_seed(3), dtype=torch.float64) * 1.6 - 0.8
    f, omega = current(x, create_graph=True)
    grad_f = omega - current.alpha(x)
    h = 1e-6
    for d in range(3):
        e = torch.zeros_like(x)
        e[:, d] = h
        fd = (current.f(x + e) - current.f(x - e)) / (2 * h)
        assert torch.allclose(grad_f[:, d], fd, atol=1e-6)
    assert torch.allclose(f, current.f(x))
    omega.norm(dim=-1).mean().backward()
    assert current.grid.table.grad is not None and current.grid.table.grad.abs().sum() > 0


@pytest.mark.parametrize("table_size", [1 << 18, 50])
def test_closed_form_jacobian_equals_autograd(table_size):
    g = grid(table_size)
    x = torch.rand(6, 3, generator=torch.Generator().manual_seed(4), dtype=torch.float64) * 1.8 - 0.9
    features, jacobian = g.features_and_jacobian(x)
    jac = torch.autograd.functional.jacobian(g, x)        # (6, 6, 6, 3)
    assert torch.allclose(features, g(x))
    assert torch.allclose(jacobian, torch.stack([jac[i, :, i, :] for i in range(len(x))]), atol=1e-12)


@pytest.mark.parametrize("rff", [True, False])
@pytest.mark.parametrize("coarse_to_fine", [0.0, 0.5])
def test_hand_written_pass_with_grid_features_matches_autograd(rff, coarse_to_fine):
    """NeuralCurrent with grid features takes nn.field_gradient's pass (the grid's features and Jacobian handed in
    beside the Fourier features); against the autograd path in float64: f, ω and the gradients of every
    parameter, the grid's table included, for a loss that sees both f and ω."""
    from deepcurrents.geometry import circle
    from deepcurrents.losses import current_loss
    from deepcurrents.nn import neural_current

    torch.manual_seed(5)
    current = neural_current(3, loops=[torch.tensor(circle(0.5, n=32))], num_frequencies=8, width=16, depth=2,
                            zero_init_output=False, rff_seed=0, rff=rff, coarse_to_fine=coarse_to_fine,
                            grid={"levels": 3, "base_resolution": 2, "finest_resolution": 7, "table_size": 50,
                                  "init_scale": 0.5}).double()
    current.encoding.set_progress(0.2)
    x = torch.rand(40, 3, generator=torch.Generator().manual_seed(6), dtype=torch.float64) * 1.8 - 0.9
    weights = torch.rand(40, dtype=torch.float64, generator=torch.Generator().manual_seed(7))
    results = {}
    for gradient in ("closed_form", "autograd"):
        current.gradient = gradient
        f, omega = current(x, create_graph=True)
        loss = current_loss(omega) + (weights * f).mean()
        results[gradient] = (f, omega, torch.autograd.grad(loss, list(current.parameters())))
    (f, omega, grads), (f_ref, omega_ref, grads_ref) = results["closed_form"], results["autograd"]
    assert torch.allclose(f, f_ref, rtol=1e-12, atol=1e-14)
    assert torch.allclose(omega, omega_ref, rtol=1e-10, atol=1e-13)
    for (name, _), a, b in zip(current.named_parameters(), grads, grads_ref, strict=True):
        assert torch.allclose(a, b, rtol=1e-9, atol=1e-12), name
    assert grads[[n for n, _ in current.named_parameters()].index("grid.table")].abs().sum() > 0


def test_hand_written_pass_with_grid_features_passes_gradcheck():
    """The hand-written backward's gradients for the extra features and their Jacobian (and the weights) against
    finite differences of its own forward."""
    from deepcurrents.nn.field_gradient import _FieldGradient
    from deepcurrents.nn.fourier import FourierFeatures

    gen = torch.Generator().manual_seed(8)
    encoding = FourierFeatures(3, 3, 2.0, seed=0).double()
    x = torch.rand(6, 3, generator=gen, dtype=torch.float64) * 2 - 1
    extra = torch.randn(6, 2, generator=gen, dtype=torch.float64).requires_grad_(True)
    extra_jac = torch.randn(6, 2, 3, generator=gen, dtype=torch.float64).requires_grad_(True)
    shapes = [(5, 8), (5,), (5, 5), (5,), (1, 5), (1,)]
    params = [torch.randn(*s, generator=gen, dtype=torch.float64).requires_grad_(True) for s in shapes]

    def run(extra, extra_jac, *params):
        return _FieldGradient.apply(x, encoding.frequencies, ("softplus", 1.0, 20.0), True, False, extra,
                                    extra_jac, None, *params)

    assert torch.autograd.gradcheck(run, (extra, extra_jac, *params), eps=1e-6, atol=1e-8, rtol=1e-6)


def test_fused_adam_is_an_option_with_the_loops_numbers():
    """model.optim.fused=true builds PyTorch's fused Adam; a step of it moves every weight (grid table included) as
    the authors' loop implementation does, up to rounding."""
    from deepcurrents.geometry import circle
    from deepcurrents.models import CurrentModule

    def module(fused: bool) -> CurrentModule:
        torch.manual_seed(0)
        return CurrentModule({"loops": [circle(0.5, n=16).tolist()]},
                             {"width": 8, "depth": 1, "zero_init_output": False},
                             {"lr": 1e-2, "step_size": 10, "gamma": 0.5, "fused": fused},
                             rff={"num_frequencies": 4, "seed": 0},
                             grid_encoding={"levels": 2, "base_resolution": 2, "finest_resolution": 4,
                                            "init_scale": 0.1})

    x = torch.rand(64, 3, generator=torch.Generator().manual_seed(1)) * 1.8 - 0.9
    moved = []
    for fused in (False, True):
        m = module(fused)
        opt = m.configure_optimizers()["optimizer"]
        assert bool(opt.defaults["fused"]) == fused
        before = [p.detach().clone() for p in m.parameters()]
        _, omega = m.current(x)
        omega.norm(dim=-1).mean().backward()
        opt.step()
        moved.append([p.detach() - b for p, b in zip(m.parameters(), before, strict=True)])
    for loop, fused in zip(*moved, strict=True):  # (the output's constant does not move: ω does not see it)
        assert torch.allclose(loop, fused, rtol=1e-4, atol=1e-7)
    names = [n for n, _ in module(False).named_parameters()]
    assert moved[0][names.index("current.grid.table")].abs().max() > 0


def test_state_dicts_with_the_former_corner_buffer_still_load():
    """Grids saved while the corner order was a buffer ("corners") load into today's grid unchanged."""
    g = grid()
    state = dict(g.state_dict())
    state["corners"] = torch.zeros(8, 3, dtype=torch.long)
    fresh = MultiresGrid(3, levels=3, base_resolution=2, finest_resolution=7, features=2, init_scale=1.0,
                         seed=1).double()
    fresh.load_state_dict(state)
    assert torch.equal(fresh.table, g.table)
