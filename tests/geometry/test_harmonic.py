"""Harmonic skinning weights: identity on the handles, partition of unity, rigid motions carried exactly,
harmonic (discrete Laplace equation) inside, one sentence for meshes it cannot skin."""

import igl
import numpy as np
import pytest
import trimesh

from deepcurrents.errors import UserInputError
from deepcurrents.geometry.harmonic import HarmonicSkinning


def spherical_cap():
    """The part z < 0.3 of a unit icosphere: a cap with one boundary loop."""
    sphere = trimesh.creation.icosphere(subdivisions=2)
    faces = sphere.faces[(sphere.vertices[sphere.faces][:, :, 2] < 0.3).all(1)]
    cap = trimesh.Trimesh(sphere.vertices, faces, process=False)
    cap.remove_unreferenced_vertices()
    return np.asarray(cap.vertices), np.asarray(cap.faces)


@pytest.fixture(scope="module")
def cap_skinning():
    v, f = spherical_cap()
    handles = np.concatenate(igl.boundary_loop_all(f))
    return HarmonicSkinning(v, f, handles)


def test_weights_are_identity_on_handles_and_sum_to_one(cap_skinning):
    w = cap_skinning.weights()
    h = cap_skinning.handles
    assert w.shape == (cap_skinning.num_vertices, len(h))
    np.testing.assert_allclose(w[h], np.eye(len(h)), atol=1e-12)
    np.testing.assert_allclose(w.sum(1), 1.0, atol=1e-10)


def test_uniform_translation_moves_the_mesh_rigidly(cap_skinning):
    v, h = cap_skinning.vertices, cap_skinning.handles
    moved = cap_skinning.deform(v[h] + np.array([0.1, -0.2, 0.05]))
    np.testing.assert_allclose(moved - v, np.broadcast_to([0.1, -0.2, 0.05], v.shape), atol=1e-10)


def test_affine_boundary_motion_of_a_flat_mesh_is_reproduced():
    # on a planar mesh linear functions are discrete-harmonic (linear precision of the cotangent
    # Laplacian), so an affine map of Γ maps the whole mesh by the same affine map
    sphere = trimesh.creation.icosphere(subdivisions=2)
    faces = sphere.faces[(sphere.vertices[sphere.faces][:, :, 2] < -0.5).all(1)]
    disc = trimesh.Trimesh(sphere.vertices * [1, 1, 0], faces, process=False)
    disc.remove_unreferenced_vertices()
    v, f = np.asarray(disc.vertices), np.asarray(disc.faces)
    skin = HarmonicSkinning(v, f, np.concatenate(igl.boundary_loop_all(f)))
    a = np.array([[1.1, 0.2, 0.0], [-0.1, 0.9, 0.05], [0.0, 0.1, 1.2]])
    b = np.array([0.3, -0.1, 0.2])
    h = skin.handles
    np.testing.assert_allclose(skin.deform(v[h] @ a.T + b), v @ a.T + b, atol=1e-10)


def test_interior_displacements_satisfy_the_laplace_equation(cap_skinning):
    v, f, h = cap_skinning.vertices, cap_skinning.faces, cap_skinning.handles
    rng = np.random.default_rng(0)
    d = cap_skinning.propagate(rng.normal(size=(len(h), 3)))
    lap = igl.cotmatrix(v, f)
    interior = np.setdiff1d(np.arange(len(v)), h)
    np.testing.assert_allclose((lap @ d)[interior], 0.0, atol=1e-10)


def test_matches_libigl_harmonic(cap_skinning):
    # an independent solver: igl.harmonic with k = 1 (Laplace), the same boundary conditions
    v, f, h = cap_skinning.vertices, cap_skinning.faces, cap_skinning.handles
    bc = np.random.default_rng(1).normal(size=(len(h), 3))
    np.testing.assert_allclose(cap_skinning.propagate(bc), igl.harmonic(v, f, h, bc, 1), atol=1e-8)


def test_a_part_without_boundary_is_one_sentence():
    v, f = spherical_cap()
    island = trimesh.creation.icosphere(subdivisions=1)
    v2 = np.concatenate([v, island.vertices * 0.1 + 2.0])
    f2 = np.concatenate([f, island.faces + len(v)])
    handles = np.concatenate(igl.boundary_loop_all(f))
    with pytest.raises(UserInputError, match="no boundary vertex"):
        HarmonicSkinning(v2, f2, handles, name="two_parts")
