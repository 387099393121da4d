"""The sharpened area bound (eval.certificate) against independent truth: κ = 0 is the plain uniform mass
bound; on a planar circle the phase mesh of α alone is the flat disk (a level set of the solid angle), so the
bound concentrated on it must come down from the plain bound (2.3× the disk) to the disk's exact area πR²,
never below it (the von Mises map itself: tests/geometry/test_phase_map.py)."""

import math

import numpy as np
import pytest
import torch

from deepcurrents.data.sampling import mesh_cell_scores, mesh_sampler
from deepcurrents.eval.certificate import sharpened_mass_estimate
from deepcurrents.eval.meshing import extract_surface
from deepcurrents.eval.metrics import mass_estimate, mass_to_area
from deepcurrents.geometry import circle
from deepcurrents.nn import neural_current

R = 0.5


@pytest.fixture(scope="module")
def untrained():
    """f ≡ const (zero-initialised output): ω = alpha_scale·α, and its phase mesh (the disk)."""
    torch.manual_seed(0)
    current = neural_current(3, loops=[torch.tensor(circle(R, n=128)).float()], num_frequencies=8, width=8, depth=1)
    result = extract_surface(current, resolution=40)
    return current, result


def test_mesh_cells_are_a_distribution_on_the_mesh():
    import trimesh

    square = trimesh.Trimesh([[-0.5, -0.5, 0.01], [0.5, -0.5, 0.01], [0.5, 0.5, 0.01], [-0.5, 0.5, 0.01]],
                             [[0, 1, 2], [0, 2, 3]])
    p = mesh_cell_scores(square, 8, spread=0).reshape(8, 8, 8)
    assert p.sum() == pytest.approx(1.0)
    assert p[:, :, 4].sum() == pytest.approx(1.0)      # z = 0.01 lies in the cells 4 of 8 along z


@pytest.mark.parametrize("tube_radius", [0.0, 0.05])
def test_kappa_zero_is_the_plain_mass_bound(untrained, tube_radius):
    """With a tube about Γ integrated apart (by samples ∝ 1/r) the estimate is the same, each point counted once."""
    current, result = untrained
    plain, plain_err = mass_estimate(current, 1 << 16, seed=3)
    plain_area = mass_to_area(plain, 3, current.alpha_scale)
    bound, err = sharpened_mass_estimate(current, mesh_sampler(result.mesh, seed=4), result.level + math.pi,
                                         kappa=0.0, num_samples=1 << 16, tube_radius=tube_radius, seed=4)
    both = math.hypot(err, mass_to_area(plain_err, 3, current.alpha_scale))
    assert abs(bound - plain_area) < 4 * both
    assert plain_area > 2.0 * math.pi * R**2             # α alone is far from the minimal current


@pytest.mark.parametrize("tube_radius", [0.0, 0.05])
def test_concentrated_on_the_disk_it_certifies_the_disk_area(untrained, tube_radius):
    current, result = untrained
    disk = math.pi * R**2
    assert result.mesh.area == pytest.approx(disk, rel=0.02)
    bound, err = sharpened_mass_estimate(current, mesh_sampler(result.mesh, seed=5), result.level + math.pi,
                                         kappa=30.0, num_samples=1 << 16, tube_radius=tube_radius, seed=5)
    assert err < 0.02 * disk
    assert bound > disk - 4 * err                        # an upper bound of the minimal area …
    assert bound < disk * 1.03 + 4 * err                 # … and, concentrated on the disk, a tight one
    assert np.isfinite(bound)


class _GaussianSheet(torch.nn.Module):
    """A current on the plane z = 0: ω = c·J·φ_σ(z) e_z with φ_σ the N(0, σ²) density, so ∫ ω·n dz over
    [−h, h] is c·J·erf(h / σ√2) (hand-computed) and |ω| integrates to c·J per unit area."""

    dim = 3
    alpha_scale = 1e-3

    def __init__(self, c: float, sigma: float):
        super().__init__()
        self.c, self.sigma = c, sigma
        self.anchor = torch.nn.Parameter(torch.zeros(()))  # for device_of

    def forward(self, x, create_graph=False):
        z = x[:, 2:3]
        density = torch.exp(-0.5 * (z / self.sigma) ** 2) / (self.sigma * math.sqrt(2 * math.pi))
        omega = torch.cat([torch.zeros_like(z), torch.zeros_like(z), self.c * 4 * math.pi * self.alpha_scale * density],
                          1)
        return None, omega


@pytest.mark.parametrize(("c", "sigma"), [(1.0, 0.004), (0.5, 0.004), (1.0, 0.04)])
def test_sheet_flux_is_the_share_of_the_jump_across_the_mesh(c, sigma):
    """sheet_flux on a square mesh of z = 0 (either orientation): c·erf(0.04 / σ√2), i.e. 1 for a full sharp sheet,
    0.5 for half the jump, 0.683 for a sheet smeared with σ equal to the window's half width."""
    import trimesh

    from deepcurrents.eval.metrics import sheet_flux

    square = trimesh.Trimesh([[-0.5, -0.5, 0], [0.5, -0.5, 0], [0.5, 0.5, 0], [-0.5, 0.5, 0]], [[0, 1, 2], [0, 2, 3]],
                             process=False)
    expected = c * math.erf(0.04 / (sigma * math.sqrt(2)))
    for mesh in (square, trimesh.Trimesh(square.vertices, square.faces[:, ::-1], process=False)):
        flux = sheet_flux(_GaussianSheet(c, sigma), mesh, num_lines=50, num_steps=161)
        assert flux.shape == (50,)
        np.testing.assert_allclose(flux, expected, rtol=2e-3)
