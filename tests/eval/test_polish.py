"""The polished mesh of a minimal surface against exact areas: the flat polygon, the catenoid, Enneper's surface; a
neck that must pinch; Richardson extrapolation and the topology it reports."""

import math

import numpy as np
import pytest
import trimesh
from conftest import disk_mesh, ring
from scipy.optimize import brentq

from deepcurrents.eval.meshing.polish import (
    PolishSettings,
    fill_holes_off_curve,
    pinkall_polthier,
    polish_minimal_surface,
    richardson,
)
from deepcurrents.eval.metrics import boundary_error
from deepcurrents.geometry.curves import enneper, enneper_area
from deepcurrents.geometry.topology import border_edges, surface_topology


def tube_mesh(bottom, top, rows):
    """A strip of triangles between two loops of the same length n (rows − 1 rings between them, linearly)."""
    n = len(bottom)
    rings = [(1 - s) * bottom + s * top for s in np.linspace(0, 1, rows + 1)]
    verts = np.concatenate(rings)
    faces = []
    for r in range(rows):
        i = r * n + np.arange(n)
        j = (r + 1) * n + np.arange(n)
        faces += [np.stack([i, np.roll(i, -1), j], 1), np.stack([np.roll(i, -1), np.roll(j, -1), j], 1)]
    return verts, np.concatenate(faces)


def catenoid_area(radius, half_height):
    """The stable catenoid between coaxial rings of ``radius`` at z = ±half_height: a·cosh(h/a) = R, the larger a;
    area π a (2h + a sinh(2h/a))."""
    a = brentq(lambda a: a * math.cosh(half_height / a) - radius, 1.2 * half_height, radius)
    return math.pi * a * (2 * half_height + a * math.sinh(2 * half_height / a))


FAST = PolishSettings(edge_length=0.04, levels=3)


def test_flat_polygon_polishes_to_its_exact_area_with_the_border_on_it():
    loop = ring(0.5, 0.0, 48)
    verts, faces = disk_mesh(loop, 6, bump=0.2)  # a dome over the polygon: 16 % too much area
    result = polish_minimal_surface(trimesh.Trimesh(verts, faces, process=False), [loop], FAST)
    exact = 48 / 2 * 0.25 * math.sin(2 * math.pi / 48)  # the regular 48-gon
    assert result.stopped is None
    assert all(math.isclose(a, exact, rel_tol=1e-9) for a in result.areas)
    assert abs(np.asarray(result.mesh.vertices)[:, 2]).max() < 1e-9
    assert boundary_error(result.mesh, [loop]) < 1e-12
    assert result.topology.describe().startswith("a disk (genus 0, 1 border loop, χ = 1)")


def test_catenoid_from_a_cylinder_reaches_the_exact_area_as_its_rings_are_refined():
    radius, half, exact = 0.5, 0.2, catenoid_area(0.5, 0.2)
    shortfall = {}
    for n in (240, 480):
        bottom, top = ring(radius, -half, n), ring(radius, half, n)
        verts, faces = tube_mesh(bottom, top, 8)  # the cylinder: the right topology, 3 % too much area
        loops = [top[::-1].copy(), bottom]  # Γ's orientation does not matter to the area
        result = polish_minimal_surface(trimesh.Trimesh(verts, faces, process=False), loops, FAST)
        assert result.stopped is None and result.topology.describe().startswith("an annulus")
        assert result.areas == sorted(result.areas, reverse=True) and result.extrapolated_error < 1e-5 * exact
        assert boundary_error(result.mesh, loops) < 1e-9
        shortfall[n] = 1 - result.extrapolated / exact
        # extrapolated in the rings' sampling too (the polygon of every other vertex): the circles' catenoid
        assert result.curve_extrapolated == pytest.approx(exact, rel=1e-5)
    # what is left is the n-gons' own shortfall from the circles, ∝ 1/n²: a quarter at twice the vertices
    assert 0 < shortfall[480] < shortfall[240] < 1e-4
    assert shortfall[240] / shortfall[480] == pytest.approx(4.0, rel=0.15)


def test_enneper_from_a_flat_disk_reaches_the_exact_area():
    (loop,) = enneper(300, radius=0.6)
    verts, faces = disk_mesh(loop, 10)
    result = polish_minimal_surface(trimesh.Trimesh(verts, faces, process=False), [loop],
                                    PolishSettings(edge_length=0.05, levels=3))
    assert result.stopped is None
    assert abs(result.extrapolated / enneper_area(0.6) - 1) < 3e-4


def test_a_neck_beyond_the_catenoids_reach_pinches_and_the_mesh_is_kept():
    # no catenoid spans rings R = 0.5 at z = ±0.4 (h/R > 0.6627): the flow thins the cylinder's neck to a pinch
    bottom, top = ring(0.5, -0.4, 120), ring(0.5, 0.4, 120)
    verts, faces = tube_mesh(bottom, top, 12)
    mesh = trimesh.Trimesh(verts, faces, process=False)
    result = polish_minimal_surface(mesh, [top[::-1].copy(), bottom], PolishSettings(edge_length=0.1, levels=2))
    assert result.stopped is not None and ("pinch" in result.stopped or "no stable minimum" in result.stopped)
    assert result.mesh is mesh and result.area == mesh.area and result.area_error is None


def test_richardson_is_exact_for_a_quadratic_error():
    areas = [2.0 + 0.3 * h**2 + 0.01 * h**4 for h in (0.1, 0.05, 0.025)]
    value, error = richardson(areas)  # R_k = 2 − 0.04 h_k⁴: the h⁴ term is what is left
    assert math.isclose(value, 2.0 - 0.04 * 0.025**4, rel_tol=1e-12)
    assert math.isclose(error, 0.04 * (0.05**4 - 0.025**4), rel_tol=1e-6) and error > abs(value - 2.0)
    value, error = richardson(areas[:2])
    assert math.isclose(error, abs(areas[1] - value)) and richardson(areas[:1]) == (None, None)


def test_pinkall_polthier_flattens_a_bump_in_one_step():
    # a planar border: the Dirichlet minimiser of any metric is planar (harmonic z with z = 0 on the border)
    loop = ring(1.0, 0.0, 16)
    verts, faces = disk_mesh(loop, 3, bump=0.5)
    fixed = np.unique(border_edges(faces))
    moved, areas = pinkall_polthier(verts, faces, fixed, tolerance=1e-12, max_iterations=1)
    assert abs(moved[:, 2]).max() < 1e-12 and areas[1] < areas[0] and len(areas) == 2


def test_a_hole_off_the_curve_is_filled_and_the_topology_counts_it():
    loop = ring(0.5, 0.0, 32)
    verts, faces = disk_mesh(loop, 4)
    inner = len(faces) - 32  # the centre fan: a hole of 32 edges where it is left out
    holed = faces[:inner]
    assert surface_topology(holed).describe().startswith("an annulus")
    v, f, filled = fill_holes_off_curve(verts, holed, [loop], 1e-9)
    assert filled == 1 and surface_topology(f).describe().startswith("a disk")
    assert math.isclose(trimesh.Trimesh(v, f, process=False).area, trimesh.Trimesh(verts, faces).area, rel_tol=1e-12)


@pytest.mark.parametrize(("genus", "border"), [(0, 1), (1, 1), (0, 3)])
def test_surface_topology_of_known_surfaces(genus, border):
    if genus == 1:  # a torus with one face removed: χ = −1
        torus = trimesh.creation.torus(1.0, 0.3, major_sections=12, minor_sections=8)
        faces = np.asarray(torus.faces)[1:]
    elif border == 3:  # a disk with two holes: χ = −1
        verts, faces = disk_mesh(ring(1.0, 0.0, 24), 6)
        faces = np.delete(faces, [60, 100], axis=0)
    else:
        verts, faces = disk_mesh(ring(1.0, 0.0, 12), 2)
    topo = surface_topology(faces)
    assert (topo.genus, topo.border_loops, topo.components, topo.manifold) == (genus, border, 1, True)
    assert topo.euler_characteristic == 2 - 2 * genus - border


def test_a_stable_catenoid_beyond_the_switch_keeps_its_topology():
    # h/R = 0.56: two disks (2πR²) have 5 % less area, but the catenoid is a stable minimum of the annulus: the flow
    # keeps the regime it is given (the current decides it), and reaches that catenoid's area
    radius, half = 0.5, 0.28
    bottom, top = ring(radius, -half, 240), ring(radius, half, 240)
    verts, faces = tube_mesh(bottom, top, 10)
    result = polish_minimal_surface(trimesh.Trimesh(verts, faces, process=False), [top[::-1].copy(), bottom], FAST)
    assert result.stopped is None and result.topology.describe().startswith("an annulus")
    assert surface_topology(result.mesh.faces) == result.topology
    assert result.curve_extrapolated == pytest.approx(catenoid_area(radius, half), rel=2e-5)
    assert result.curve_extrapolated > 2 * math.pi * radius**2


def test_a_remesher_failure_keeps_the_extracted_mesh(monkeypatch):
    import gpytoolbox

    def refuse(*args, **kwargs):
        raise RuntimeError("non-manifold input")

    monkeypatch.setattr(gpytoolbox, "remesh_botsch", refuse)
    loop = ring(0.5, 0.0, 32)
    mesh = trimesh.Trimesh(*disk_mesh(loop, 3, bump=0.1), process=False)
    result = polish_minimal_surface(mesh, [loop], FAST)
    assert result.stopped == "the remesher failed (non-manifold input)" and result.mesh is mesh
    assert result.extrapolated is None and result.area == mesh.area
