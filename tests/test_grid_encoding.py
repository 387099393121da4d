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
    from deepcurrents.models.base import network_kwargs

    for bad in (-1, 2.5, True):  # a negative level count used to switch the grid off silently
        with pytest.raises(ConfigError, match="model.grid_encoding.levels"):
            network_kwargs({"width": 8, "depth": 1}, None, {"levels": bad})
    assert "grid" not in network_kwargs({"width": 8, "depth": 1}, None, {"levels": 0})


def test_current_with_grid_features_has_omega_equal_to_grad_f_plus_alpha():
    """NeuralCurrent with grid features: ω − alpha_scale·α is ∇f by central differences (float64), and the
    training backward reaches the grid table."""
    from deepcurrents.geometry import circle
    from deepcurrents.nn import NeuralCurrent

    torch.manual_seed(0)
    current = NeuralCurrent(3, loops=[torch.tensor(circle(0.5, n=32))], num_frequencies=8, width=16, depth=2,
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
