"""Shared test plumbing: deterministic seeds, the project's config directory, composing the root config as
`python train.py ...` does, and the override lists that make runs tiny.

Tests import the helpers (`from conftest import compose_cfg, QUIET_CPU, TINY_NET`): they are needed at import
time (parametrize lists, module-scoped fixtures), where a function-scoped pytest fixture cannot go.
Tests that train for more than a few seconds carry `@pytest.mark.slow`: `pytest -m "not slow"` skips them,
`make test` runs everything."""

from __future__ import annotations

import importlib
import importlib.util
import io
import logging
import os
import sys
import traceback
from collections.abc import Iterator, Sequence
from contextlib import contextmanager, redirect_stderr, redirect_stdout
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
import trimesh
from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from omegaconf import DictConfig, OmegaConf

from deepcurrents.data.body_partition import BodyPart

ROOT = Path(__file__).resolve().parents[1]
CONF_DIR = str(ROOT / "conf")

# A run on the CPU preset that prints and logs nothing (no progress bar, no model table, no logger, no media).
QUIET_CPU = [
    "logger=none", "preset=cpu", "trainer=cpu", "trainer.enable_progress_bar=false",
    "trainer.enable_model_summary=false", "callbacks.media=null",
]
# A network and batch small enough for a training step in milliseconds.
TINY_NET = ["data.num_samples=64", "model.rff.num_frequencies=16", "model.net.width=16", "model.net.depth=2"]
# Cheap final evaluation: a coarse mesh, few Monte Carlo samples for the mass bound and the UCD, a coarse polish.
TINY_EVAL = ["evaluation.mass_samples=4096", "evaluation.ucd_samples=4000", "evaluation.mesh.resolution=24",
             "evaluation.mesh.polish.edge_length=0.1", "evaluation.mesh.polish.levels=2"]


@contextmanager
def hydra_context() -> Iterator[None]:
    """Hydra initialised on the project's conf/ (what suites need to compose their members)."""
    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        yield


def compose_cfg(overrides: Sequence[str], hydra_config: bool = False) -> DictConfig:
    """The root config `train` with these command-line overrides (`hydra_config`: keep the `hydra` node)."""
    with hydra_context():
        return compose(config_name="train", overrides=list(overrides), return_hydra_config=hydra_config)


def validate_overrides(overrides: Sequence[str]) -> None:
    """The root config with these overrides, checked as a run checks it before anything is built
    (``experiments.schema``): a bad setting raises its one-sentence ConfigError here."""
    from deepcurrents.experiments.config import validate_config

    validate_config(compose_cfg(overrides))


def load_benchmark(name: str):
    """A script of benchmarks/ (not a package) imported as a module, for tests of its helpers."""
    spec = importlib.util.spec_from_file_location(name, ROOT / "benchmarks" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def spherical_cap(radius: float = 0.5, height: float = 0.25, subdivisions: int = 3,
                  centre: Sequence[float] = (0.0, 0.0, 0.0)) -> trimesh.Trimesh:
    """The part of a sphere (centre at the origin, then shifted by ``centre``) above z = radius − height,
    outward normals: an open surface whose rim is one circle; its Euclidean minimal surface is the flat disk."""
    sphere = trimesh.creation.icosphere(subdivisions, radius=radius)
    keep = sphere.triangles_center[:, 2] > radius - height
    cap = trimesh.Trimesh(sphere.vertices + np.asarray(centre), sphere.faces[keep])
    cap.remove_unreferenced_vertices()
    return cap


def write_oriented_cloud(mesh: trimesh.Trimesh, folder: Path, count: int = 3000) -> tuple[Path, Path, np.ndarray]:
    """An oriented point cloud of ``mesh`` (``count`` surface samples, seed 0) as cloud.xyz (x y z nx ny nz) and
    its first border loop as rim.txt, in ``folder``. → (cloud path, rim path, the points (count, 3))."""
    from deepcurrents.data.targets import mesh_boundary_loops, sample_mesh_surface

    pts, nrm = sample_mesh_surface(np.asarray(mesh.vertices), np.asarray(mesh.faces), count,
                                   torch.Generator().manual_seed(0))
    np.savetxt(folder / "cloud.xyz", np.hstack([pts, nrm]))
    np.savetxt(folder / "rim.txt", mesh_boundary_loops(mesh.vertices, mesh.faces)[0])
    return folder / "cloud.xyz", folder / "rim.txt", np.asarray(pts)


def written_curve_length(path: Path) -> float:
    """The total length of the open polylines in a 2D run's curve.npz (one (K, 2) array per piece)."""
    pieces = np.load(path)
    return float(sum(np.linalg.norm(np.diff(pieces[k], axis=0), axis=1).sum() for k in pieces.files))


def app_cfg(schema: type, **values: Any) -> DictConfig:
    """An app's structured config (e.g. ``RenderConfig``) with dotted ``values`` set, as its command line would."""
    cfg = OmegaConf.structured(schema)
    for key, value in values.items():
        OmegaConf.update(cfg, key, value)
    return cfg


TRAIN_COMMAND = "deepcurrents.cli.train"  # the module whose main `python train.py …` runs


@dataclass
class CommandResult:
    """What a command left: its exit status and what it printed."""

    returncode: int
    stdout: str
    stderr: str


def run_command_in_process(module: str, args: Sequence[str], cwd: Path) -> CommandResult:
    """``python -m <module> <args>`` run in this process (``module``'s Hydra ``main``, ``sys.argv`` as the shell
    gives it, from ``cwd``): the command line's code path without a new interpreter's ~8 s of imports.

    An exception that escapes is written to stderr as the interpreter would (exit status 1), so a test's
    "no Traceback" check still sees it. Hydra's global state and the logging set-up it installs are undone
    afterwards, so later tests in this process start clean. (One real subprocess per kind of entry point
    stays in test_apps/test_train.)"""
    main = importlib.import_module(module).main
    root = logging.getLogger()
    handlers, level = root.handlers[:], root.level
    # a logging config with disable_existing_loggers (hydra/job_logging=disabled) would silence later tests' caplog
    disabled = {name: lg.disabled for name, lg in logging.root.manager.loggerDict.items()
                if isinstance(lg, logging.Logger)}
    out, err = io.StringIO(), io.StringIO()
    argv, here = sys.argv, os.getcwd()
    code = 0
    GlobalHydra.instance().clear()
    try:
        sys.argv = [module, *args]
        os.chdir(cwd)
        with redirect_stdout(out), redirect_stderr(err):
            try:
                main()
            except SystemExit as stop:
                code = stop.code if isinstance(stop.code, int) else (0 if stop.code is None else 1)
            except Exception:  # noqa: BLE001 -- what the interpreter would print
                traceback.print_exc(file=err)
                code = 1
    finally:
        sys.argv = argv
        os.chdir(here)
        GlobalHydra.instance().clear()
        for handler in set(root.handlers) - set(handlers):  # Hydra's: the run's log file, the captured stdout
            handler.close()
        root.handlers[:] = handlers
        root.setLevel(level)
        for name, lg in logging.root.manager.loggerDict.items():
            if isinstance(lg, logging.Logger):
                lg.disabled = disabled.get(name, False)
    return CommandResult(code, out.getvalue(), err.getvalue())


class Payload:
    """Unpickling this object runs a shell command (what a crafted checkpoint would do)."""

    def __init__(self, command: str):
        self.command = command

    def __reduce__(self):
        return (os.system, (self.command,))


@pytest.fixture(scope="module")
def one_thread():
    """One torch thread for a module (`pytestmark = pytest.mark.usefixtures("one_thread")`): the machine is
    shared, contended threads run slower, and one thread adds reductions in the same order as subprocesses."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="session")
def cap_file(tmp_path_factory) -> Path:
    """A spherical cap (`spherical_cap()`) as a .ply file."""
    path = tmp_path_factory.mktemp("cap") / "cap.ply"
    spherical_cap().export(path)
    return path


@pytest.fixture(scope="session")
def parts_root(tmp_path_factory) -> Path:
    """A tiny human-part-like dataset in the generator's layout, root/anny/<category>/000.ply: one small
    cap per category (`data.root=<this>` makes every recon_<part> experiment runnable)."""
    from deepcurrents.data.human_parts_builder import write_parts

    root = tmp_path_factory.mktemp("parts")
    cap = spherical_cap(height=0.2, subdivisions=2)
    categories = ("heads", "hands", "forearms", "arms", "torsos", "feet")
    write_parts({c: ([cap.vertices], cap.faces, 1.0) for c in categories}, root, "anny")
    return root


def pytest_configure(config: pytest.Config) -> None:
    """Under pytest-xdist (`make test` runs `-n auto`) each worker gets its share of the cores for torch: workers
    that each spun a thread per core would oversubscribe them, and contended threads run slower than one."""
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "0"))
    if workers > 1:
        torch.set_num_threads(max(1, (os.cpu_count() or 1) // workers))


@pytest.fixture(autouse=True)
def _seed():
    torch.manual_seed(0)
    np.random.seed(0)
    yield


# ------------------------------------------------------------------------------------------ a tiny family
def disc_mesh(height, rings: int = 6, sectors: int = 24, radius: float = 0.35, center=(0.0, 0.0, 0.0)):
    """A polar-grid disc z = height(x, y) (one boundary loop, normals towards +z), shifted by ``center``."""
    r = np.repeat(np.arange(1, rings + 1) / rings * radius, sectors)
    t = np.tile(np.arange(sectors) / sectors * 2 * np.pi, rings)
    xy = np.concatenate([[[0.0, 0.0]], np.stack([r * np.cos(t), r * np.sin(t)], 1)])
    v = np.concatenate([xy, height(xy[:, 0], xy[:, 1])[:, None]], 1) + np.asarray(center)
    j = np.arange(sectors)
    faces = [np.stack([np.zeros(sectors, int), 1 + j, 1 + (j + 1) % sectors], 1)]
    for i in range(rings - 1):
        a, b = 1 + i * sectors, 1 + (i + 1) * sectors
        faces += [np.stack([a + j, b + j, b + (j + 1) % sectors], 1),
                  np.stack([a + j, b + (j + 1) % sectors, a + (j + 1) % sectors], 1)]
    return trimesh.Trimesh(v, np.concatenate(faces), process=False)


SHAPES = {
    "000_cap": lambda x, y: 1.6 * (0.35**2 - x**2 - y**2),
    "001_saddle": lambda x, y: 1.5 * (x**2 - y**2),
    "002_wave": lambda x, y: 0.08 * np.sin(9 * x) - 0.6 * (0.35**2 - x**2 - y**2),
}


# a training family: three different small discs, apart in space so that a few hundred CPU steps suffice
CENTRES = {"000_cap": (-0.5, 0.0, 0.0), "001_saddle": (0.5, 0.0, 0.0), "002_wave": (0.0, 0.0, 0.55)}


def write_family(d: Path) -> Path:
    """The training family (SHAPES at CENTRES) as d/NNN_name.ply. → d"""
    for name, h in SHAPES.items():
        disc_mesh(h, radius=0.25, center=CENTRES[name]).export(d / f"{name}.ply")
    return d


def tiny_overrides(path: Path, out: Path, steps: int) -> list[str]:
    """The CPU preset shrunk further. No augmentation and the surface loss weighted ×5 so that the small
    network leaves the flat-f start within ~100 steps (augmentation has its own tests above); σ = 2 and δ = 0.01
    (the former preset's): in 150 steps the σ = 4 network's members are fog, whose large meshes made the brute-force
    border checks of the interpolation test take 75 s instead of 17."""
    return [
        "experiment=latent_hands", "preset=cpu", "logger=none", f"data.path={path}", f"paths.output_dir={out}",
        f"trainer.max_steps={steps}", "trainer.enable_progress_bar=false", "trainer.enable_model_summary=false",
        "data.meshes_per_batch=3", "data.num_samples=256", "data.num_surface_samples=192", "data.num_workers=0",
        "data.augment=false", "model.latent_dim=16", "model.boundary_dim=16", "model.surface_weight=5",
        "model.optim.lr=2e-3", f"model.optim.step_size={steps}", "evaluation.ucd_samples=4000",
        "evaluation.mesh.resolution=40", f"callbacks.model_checkpoint.every_n_train_steps={steps}",
        "callbacks.media=null", "model.rff.sigma=2", "model.surface_margin=0.01",
        "model.optim.schedule=step", "model.latent_lr_factor=1",
    ]


def ring(radius, z, n, reverse=False):
    """A regular n-gon of ``radius`` in the plane at height z, counter-clockwise (``reverse``: clockwise). → (n, 3)."""
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    t = -t if reverse else t
    return np.stack([radius * np.cos(t), radius * np.sin(t), np.full(n, z)], 1)


def disk_mesh(loop, rows, bump=0.0):
    """A fan-like disk spanning one loop: rings shrinking to its centroid, lifted by ``bump``·(1 − r²)."""
    centre = loop.mean(0)
    n = len(loop)
    rings = [centre + s * (loop - centre) for s in np.linspace(1, 0, rows + 1)[:-1]]
    verts = np.concatenate(rings + [centre[None]])
    s = np.concatenate([np.full(n, v) for v in np.linspace(1, 0, rows + 1)[:-1]] + [[0.0]])
    verts[:, 2] += bump * (1 - s**2)
    faces = []
    for r in range(rows - 1):
        i, j = r * n + np.arange(n), (r + 1) * n + np.arange(n)
        faces += [np.stack([i, np.roll(i, -1), j], 1), np.stack([np.roll(i, -1), np.roll(j, -1), j], 1)]
    last = (rows - 1) * n + np.arange(n)
    faces.append(np.stack([last, np.roll(last, -1), np.full(n, rows * n)], 1))
    return verts, np.concatenate(faces)


# A three-part body for the stitched-body tests (tests/data/test_body_partition.py, tests/experiments/test_train.py)
CHAIN = (BodyPart("torso", r"^root$", None, None), BodyPart("limb", r"^limb$", "torso", "shoulder"),
         BodyPart("hand", r"^hand$", "limb", "wrist"))


def synthetic_body(hidden_cap: bool = False):
    """An ellipsoid along z (half-length 2) with bones root, limb, hand: the limb's subtree share is 1/2 at z = 0 and
    the hand's at z = 1, both linear in z around there; ``hidden_cap``: the faces around the bottom pole hidden."""
    sphere = trimesh.creation.icosphere(subdivisions=3)
    verts = np.asarray(sphere.vertices) * [1.0, 1.0, 2.0]
    z = verts[:, 2]
    hand = np.clip(z - 0.5, 0, 1)  # 1/2 at z = 1
    limb_subtree = np.clip(z + 0.5, 0, 1)  # 1/2 at z = 0
    weights = np.stack([1 - limb_subtree, limb_subtree - hand, hand], 1)
    faces = np.asarray(sphere.faces)
    hidden = verts[faces][:, :, 2].mean(1) < -1.9 if hidden_cap else None
    return verts, faces, weights, ["root", "limb", "hand"], hidden
