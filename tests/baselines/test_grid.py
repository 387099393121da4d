"""The grid baseline of Fig. 4 (Wang & Chern 2021): cosine transforms, the discrete d, the Poisson step,
the shrink step against closed forms and brute force; ADMM on a circle against the disk's area as the
grid is refined; the Lightning run and the fig4 suite at tiny sizes."""

import json
import math

import numpy as np
import pytest
import scipy.fft
import torch
from conftest import QUIET_CPU, TINY_NET, compose_cfg, hydra_context

from deepcurrents.baselines.grid_solver import (
    GridProblem,
    admm_init,
    admm_step,
    cap_singularity,
    cell_centers,
    dct,
    dctn,
    grid_gradient,
    grid_gradient_adjoint,
    grid_spacing,
    grid_vertices,
    idct,
    poisson_eigenvalues,
    shrink,
    solve_poisson,
    trapezoid_weights,
)
from deepcurrents.errors import ConfigError
from deepcurrents.experiments.runner import train
from deepcurrents.geometry import biot_savart, circle

F64 = torch.float64


# ------------------------------------------------------------------------------------------ transforms

@pytest.mark.parametrize("n", [1, 2, 5, 8, 9])
def test_dct_matches_scipy_and_inverts(n):
    x = torch.randn(n, 3, 4, dtype=F64)
    for dim in (0, 1, 2):
        ref = scipy.fft.dct(x.numpy(), type=2, norm="ortho", axis=dim)
        assert np.allclose(dct(x, dim).numpy(), ref, atol=1e-13)
        assert torch.allclose(idct(dct(x, dim), dim), x, atol=1e-13)
    assert np.allclose(dctn(x).numpy(), scipy.fft.dctn(x.numpy(), type=2, norm="ortho"), atol=1e-13)


# ---------------------------------------------------------------------------------------- discrete d

def dense_operator(n):
    """G as a dense matrix ((N+1)³·3, N³), column j = G applied to the j-th unit grid function."""
    h = grid_spacing(n)
    eye = torch.eye(n**3, dtype=F64).reshape(n**3, n, n, n)
    return torch.stack([grid_gradient(e, h).reshape(-1) for e in eye], 1)


def test_gradient_of_a_linear_function_is_exact_inside_and_neumann_on_the_boundary():
    n = 6
    h = grid_spacing(n)
    a = torch.tensor([0.3, -1.2, 2.0], dtype=F64)
    phi = cell_centers(n) @ a
    g = grid_gradient(phi, h)  # (3, N+1, N+1, N+1)
    inner = g[:, 1:-1, 1:-1, 1:-1].reshape(3, -1)
    assert torch.allclose(inner, a[:, None].expand_as(inner), atol=1e-12)
    # the reflected ghost cells make the normal component vanish on ∂U (the natural boundary condition)
    assert g[0, 0].abs().max() == 0 and g[0, -1].abs().max() == 0 and g[2, :, :, 0].abs().max() == 0


def test_adjoint_is_the_transpose():
    n = 4
    G = dense_operator(n)
    z = torch.randn(3, n + 1, n + 1, n + 1, dtype=F64)
    assert torch.allclose(grid_gradient_adjoint(z, grid_spacing(n)).reshape(-1), G.T @ z.reshape(-1), atol=1e-12)


def test_poisson_eigenvectors_are_cosines_with_the_closed_form_eigenvalues():
    """A known problem: GᵀWG of the product cosine cos(πk(i+½)/N)cos(πl(j+½)/N)cos(πm(k+½)/N) is λ times
    itself (λ by the closed form); the Poisson step returns it divided by λ, to round-off."""
    n = 7
    h = grid_spacing(n)
    w = trapezoid_weights(n)
    lam = poisson_eigenvalues(n, h)
    i = torch.arange(n, dtype=F64) + 0.5
    for k, l, m in [(1, 0, 0), (2, 3, 1), (6, 6, 6), (0, 5, 2)]:
        mode = (torch.cos(math.pi * k * i / n)[:, None, None] * torch.cos(math.pi * l * i / n)[None, :, None]
                * torch.cos(math.pi * m * i / n)[None, None, :])
        applied = grid_gradient_adjoint(grid_gradient(mode, h) * w, h)
        assert torch.allclose(applied, lam[k, l, m] * mode, atol=1e-10 * float(lam.max()))
        assert torch.allclose(solve_poisson(applied, lam), mode, atol=1e-12)


def test_poisson_step_is_the_weighted_least_squares_solution():
    """Against a dense least-squares solve of min ‖Gφ − b‖_W (minimum norm: φ mean-free)."""
    n = 4
    h = grid_spacing(n)
    G = dense_operator(n).numpy()
    w = np.tile(trapezoid_weights(n).reshape(-1).numpy(), 3)  # per entry, component-first layout
    b = np.random.default_rng(3).normal(size=G.shape[0])
    sw = np.sqrt(w)
    dense, *_ = np.linalg.lstsq(sw[:, None] * G, sw * b, rcond=None)
    rhs = grid_gradient_adjoint(torch.tensor(w * b).reshape(3, n + 1, n + 1, n + 1), h)
    ours = solve_poisson(rhs, poisson_eigenvalues(n, h)).reshape(-1).numpy()
    assert np.allclose(ours, dense - dense.mean(), atol=1e-12)
    # only the constant is in the null space: GᵀWG is otherwise invertible (no checkerboard modes)
    eig = np.linalg.eigvalsh(G.T @ (w[:, None] * G))
    assert eig[0] < 1e-9 and eig[1] > 1e-3


# -------------------------------------------------------------------------------------------- shrink

def test_shrink_matches_its_closed_form_and_is_the_prox():
    v = torch.tensor([[3.0, 4.0, 0.0], [0.3, 0.4, 0.0], [0.0, 0.0, 0.0], [1.0, -2.0, 2.0]], dtype=F64).T
    out = shrink(v, 1.0).T
    expected = torch.tensor([[2.4, 3.2, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [2 / 3, -4 / 3, 4 / 3]], dtype=F64)
    assert torch.allclose(out, expected, atol=1e-15)
    # prox of τ|·|: no random point does better on τ|z| + ½|z − v|²
    rng = np.random.default_rng(0)
    tau = 0.7
    for vec in rng.normal(size=(20, 3)):
        z = shrink(torch.tensor(vec)[:, None], tau)[:, 0].numpy()
        best = tau * np.linalg.norm(z) + 0.5 * np.sum((z - vec) ** 2)
        trials = z + 0.05 * rng.normal(size=(500, 3))
        values = tau * np.linalg.norm(trials, axis=1) + 0.5 * np.sum((trials - vec) ** 2, axis=1)
        assert values.min() >= best - 1e-12


# ---------------------------------------------------------------------------------------------- ADMM

def solve_circle(n, iterations):
    loop = torch.tensor(circle(0.6, normal=(0.0, 0.0, 1.0)))
    alpha = biot_savart(grid_vertices(n).reshape(-1, 3), [loop]).T.reshape(3, n + 1, n + 1, n + 1)
    problem = GridProblem.from_alpha(cap_singularity(alpha, grid_spacing(n)))
    state = admm_init(problem, rho=0.5 * grid_spacing(n))
    for _ in range(iterations):
        report = admm_step(problem, state, relaxation=1.6)
    lower = problem.dual_bound(state.rho * state.u)
    return report.mass / (4 * math.pi), lower / (4 * math.pi), report


def test_discrete_mass_of_a_circle_approaches_the_disk_area_as_the_grid_is_refined():
    disk = math.pi * 0.6**2
    coarse, coarse_lower, _ = solve_circle(8, 150)
    fine, fine_lower, report = solve_circle(16, 150)
    assert report.primal < 5e-3 and report.dual < 5e-3
    # the certified lower bound is below the mass, and the iteration is close to the discrete optimum
    assert coarse_lower <= coarse and fine_lower <= fine and fine - fine_lower < 0.02 * fine
    assert abs(fine - disk) < abs(coarse - disk)
    # O(h) from the cells next to Γ, where no grid function cancels α ~ 2/r (measured: +37% at 8³, +13% at 16³)
    assert abs(fine - disk) < 0.2 * disk


# ------------------------------------------------------------------------------------ Lightning runs

TINY = [*QUIET_CPU, "evaluation.mass_samples=4096", "evaluation.mesh.resolution=24"]


def test_minimal_grid_run_writes_its_files_and_resumes(tmp_path):
    cfg = compose_cfg(["experiment=minimal_grid", "data.curve=circle", "model.grid.resolution=10",
                       "trainer.max_steps=6", "callbacks.model_checkpoint.every_n_train_steps=3", *TINY])
    out = tmp_path / "run"
    metrics = train(cfg, out_dir=out)
    for name in ("metrics.json", "mesh.ply", "mesh.png", "field.npz", "checkpoints/last.ckpt"):
        assert (out / name).is_file(), name
    assert json.loads((out / "metrics.json").read_text()) == json.loads(json.dumps(metrics))
    assert metrics["parameters"] == 1000 and metrics["iterations"] == 6
    for key in ("mass_area", "mass_area_lower", "mesh_area", "boundary_error", "train_seconds"):
        assert key in metrics
    field = np.load(out / "field.npz")
    assert field["phi"].shape == (10, 10, 10) and field["omega_norm"].shape == (11, 11, 11)
    ckpt = torch.load(out / "checkpoints/last.ckpt", weights_only=False)
    assert ckpt["deepcurrents"]["module"].endswith("GridModule")
    # resume: ADMM's Z, u and ρ come back with the optimiser state, the count continues
    cfg2 = compose_cfg(["experiment=minimal_grid", "data.curve=circle", "model.grid.resolution=10",
                        "trainer.max_steps=9", f"ckpt_path={out / 'checkpoints/last.ckpt'}", *TINY])
    resumed = train(cfg2, out_dir=tmp_path / "resumed")
    assert resumed["iterations"] == 9


def test_grid_is_sized_like_the_network_and_rejects_bad_input(tmp_path):
    from deepcurrents.baselines.grid import matched_resolution

    n, count = matched_resolution(dict(width=256, depth=4), dict(num_frequencies=1024), [torch.tensor(circle())])
    assert (n, count) == (90, 725_249)  # the paper's 90³ for its 725,249 weights
    for bad, message in [(["model.grid.resolution=2"], "resolution"), (["model.admm.rho=-1"], "rho"),
                         (["experiment=minimal_grid", "data=points_2d"], "3D boundary"),
                         # ignored without a word before (the keys are read by name)
                         (["+model.grid.resolutoin=50"], r"^model\.grid\.resolutoin is not a setting of model\.grid"),
                         (["+model.admm.tols=1e-4"], r"^model\.admm\.tols is not a setting of model\.admm"),
                         # one sentence naming neither before; a negative count was taken
                         (["model.admm.tol=-1"], r"^model\.admm\.tol=-1 must be positive"),
                         (["model.admm.balance=-1"], r"^model\.admm\.balance=-1 must be non-negative"),
                         (["model.admm.min_iterations=-3"], r"^model\.admm\.min_iterations=-3 must be an integer"),
                         # torch's allocator error inside Hydra's before (1 TB in one allocation)
                         (["model.grid.resolution=5000"], r"^model\.grid\.resolution=5000 asks for about .* GiB"),
                         # Lightning's "remove Trainer(gradient_clip_val=0.1)" before, a setting nobody typed
                         (["recipe=sharp"], r"^trainer\.gradient_clip_val=0\.1 \(set by recipe=sharp, or on the")]:
        overrides = bad if bad[0].startswith("experiment") else ["experiment=minimal_grid", *bad]
        with pytest.raises(ConfigError, match=message) as info:
            train(compose_cfg([*overrides, *TINY]), out_dir=tmp_path)
        assert "\n" not in str(info.value)


def test_resuming_a_grid_at_another_resolution_names_the_resolution(tmp_path):
    """The grid's one array is φ (N, N, N): a resume at another N said model.net / model.rff sizes differ."""
    from deepcurrents.errors import UserInputError

    base = ["experiment=minimal_grid", *TINY, "trainer.max_steps=2", "model.grid.resolution=8"]
    train(compose_cfg(base), out_dir=tmp_path / "run")
    resume = [*base[:-1], "model.grid.resolution=10", f"ckpt_path={tmp_path / 'run' / 'checkpoints' / 'last.ckpt'}"]
    with pytest.raises(UserInputError, match=r"holds a 8³ grid, but this run's config builds 10³ .*"
                                             r"model\.grid\.resolution=8\)"):
        train(compose_cfg(resume), out_dir=tmp_path / "again")


def test_a_suite_refuses_an_override_that_would_make_its_members_one_problem(tmp_path):
    """experiment=fig4 data.curve=circle ran the circle six times under the three curves' names; a setting of the
    problem that the members set apart is refused in one sentence before anything runs, while one they share
    (data.category in the hand ablation) and settings of the run (trainer.max_steps) pass."""
    from deepcurrents.experiments.runner import check_suite_overrides, run_suite

    fig4, table1, ablation = (compose_cfg([f"experiment={e}"]) for e in ("fig4", "table1", "hand_ablation"))
    with hydra_context():
        with pytest.raises(ConfigError, match=r"^data\.curve=circle would choose one problem .*grid_trefoil: "
                                              r"curve=trefoil.*grid_hopf: curve=hopf"):
            run_suite(fig4, tmp_path, extra_overrides=["data.curve=circle"])
        with pytest.raises(ConfigError, match=r"^data\.category=feet would choose one problem"):
            check_suite_overrides(table1, ["data.category=feet"])
        # the members leave data.mesh unset, and a mesh wins over a category: one hand as four parts
        with pytest.raises(ConfigError, match=r"^data\.mesh=my_hand\.ply would choose one problem .*category=heads"):
            check_suite_overrides(table1, ["data.mesh=my_hand.ply"])
        check_suite_overrides(fig4, ["trainer.max_steps=3", "preset=cpu", "data.curve_vertices=300",
                                     "data.normalize=false"])
        check_suite_overrides(table1, ["data.source=faust", "data.index=3"])
        check_suite_overrides(ablation, ["data.category=feet"])
    assert not any(tmp_path.iterdir())


def test_a_suite_refuses_overrides_that_merge_its_variants_or_that_a_member_cannot_take(tmp_path):
    """experiment=hand_ablation ablation=relu made all five variants the ReLU run under five names; table1 with
    model.surface_weight=2 trained the first member, then stopped at the baseline in Hydra's words ("use +…"). Both
    are one sentence before any member trains; settings every member takes (preset, data.category) pass."""
    from deepcurrents.experiments.runner import check_suite_variants, compose_members, run_suite

    table1, ablation = (compose_cfg([f"experiment={e}"]) for e in ("table1", "hand_ablation"))
    with hydra_context():
        for override, key in (("ablation=relu", "model.rff.enabled"), ("model.net.activation=relu",
                                                                      "model.net.activation")):
            with pytest.raises(ConfigError, match=rf"^The command line's {override} would make suite members "
                                                  rf"\w+ and \w+ the same run \(they differ in .*{key}"):
                run_suite(ablation, tmp_path, extra_overrides=[override, "preset=cpu"])
        with pytest.raises(ConfigError, match=r"^Suite member baseline_head cannot run with the command line's "
                                              r"overrides \(model\.surface_weight=2\).*no such setting\)\.$"):
            run_suite(table1, tmp_path, extra_overrides=["model.surface_weight=2"])
        with pytest.raises(ConfigError, match=r"^Suite member baseline_head .*model\.surface_weight is not a setting "
                                              r"ClosestPointModule takes"):
            run_suite(table1, tmp_path, extra_overrides=["ablation=no_surface_loss"])
        overrides = ["preset=cpu", "data.category=feet"]
        check_suite_variants(ablation, overrides, compose_members(ablation, overrides, tmp_path))
    assert not any(tmp_path.iterdir())


@pytest.mark.slow
def test_fig4_suite_writes_its_figure_and_table(tmp_path):
    cfg = compose_cfg(["experiment=fig4"])
    assert [r.name for r in cfg.suite.runs] == [f"{m}_{c}" for c in ("trefoil", "hopf", "borromean")
                                                for m in ("grid", "network")]
    cfg.suite.runs = [r for r in cfg.suite.runs if r.name.endswith("_hopf")]  # one curve keeps it short
    for run in cfg.suite.runs:  # what `python train.py experiment=fig4 <overrides>` passes to each member
        run.overrides.extend([*TINY, *TINY_NET, "trainer.max_steps=3"])
    with hydra_context():
        train(cfg, out_dir=tmp_path)
    for name in ("fig4.png", "fig4.csv", "fig4.md", "suite.json"):
        assert (tmp_path / name).is_file(), name
    rows = (tmp_path / "fig4.csv").read_text().splitlines()
    assert rows[0] == ("method,curve,parameters,mass_area,mesh_area,mesh_area_polished,mesh_area_extrapolated,"
                       "mesh_area_smooth_curve,surface,boundary_error,seconds")
    table = {tuple(r.split(",")[:2]): r.split(",") for r in rows[1:]}
    assert set(table) == {("grid", "hopf"), ("network", "hopf")}
    # the grid is sized to the network: N = round(∛(weights + frozen frequencies)) = 10 here
    net = int(table[("network", "hopf")][2])
    assert net == 16 * 3 + (32 * 16 + 16) + (16 * 16 + 16) + (16 + 1)
    assert int(table[("grid", "hopf")][2]) == round(net ** (1 / 3)) ** 3 == 1000
