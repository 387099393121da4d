"""Shared test plumbing: deterministic seeds, the project's config directory, composing the root config as
`python train.py ...` does, and the override lists that make runs tiny.

Tests import the helpers (`from conftest import compose_cfg, QUIET_CPU, TINY_NET`): they are needed at import
time (parametrize lists, module-scoped fixtures), where a function-scoped pytest fixture cannot go.
Tests that train for more than a few seconds carry `@pytest.mark.slow`: `pytest -m "not slow"` skips them,
`make test` runs everything."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh
from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from omegaconf import DictConfig

ROOT = Path(__file__).resolve().parents[1]
CONF_DIR = str(ROOT / "conf")

# A run on the CPU preset that prints and logs nothing (no progress bar, no model table, no logger, no media).
QUIET_CPU = [
    "logger=none", "preset=cpu", "trainer=cpu", "trainer.enable_progress_bar=false",
    "trainer.enable_model_summary=false", "callbacks.media=null",
]
# A network and batch small enough for a training step in milliseconds.
TINY_NET = ["data.num_samples=64", "model.rff.num_frequencies=16", "model.net.width=16", "model.net.depth=2"]
# Cheap final evaluation: a coarse mesh, few Monte Carlo samples for the mass bound and the UCD.
TINY_EVAL = ["evaluation.mass_samples=4096", "evaluation.ucd_samples=4000", "evaluation.mesh.resolution=24"]


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


def spherical_cap(radius: float = 0.5, height: float = 0.25, subdivisions: int = 3) -> trimesh.Trimesh:
    """The part of a sphere (centre at the origin) above z = radius − height, outward normals: an open
    surface whose rim is a circle, with 0.5 radius; its Euclidean minimal surface is the flat disk."""
    sphere = trimesh.creation.icosphere(subdivisions, radius=radius)
    keep = sphere.triangles_center[:, 2] > radius - height
    cap = trimesh.Trimesh(sphere.vertices, sphere.faces[keep])
    cap.remove_unreferenced_vertices()
    return cap


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
    from deepcurrents.data.human_parts import write_parts

    root = tmp_path_factory.mktemp("parts")
    cap = spherical_cap(height=0.2, subdivisions=2)
    categories = ("heads", "hands", "forearms", "arms", "torsos", "feet")
    write_parts({c: ([cap.vertices], cap.faces, 1.0) for c in categories}, root, "anny")
    return root


@pytest.fixture(autouse=True)
def _seed():
    torch.manual_seed(0)
    np.random.seed(0)
    yield
