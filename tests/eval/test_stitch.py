"""Stitching parts along shared loops: two cones on one 12-gon, each with its own extra border vertices on the
loop's segments, must make one closed, consistently oriented surface whose seam is the loop, with the area and the
volume of the two cones exactly."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from deepcurrents.eval.meshing.stitch import SharedLoop, loop_parameter, stitch_parts
from deepcurrents.geometry.topology import consistently_oriented

N = 12
LOOP = np.stack([np.cos(2 * np.pi * np.arange(N) / N), np.sin(2 * np.pi * np.arange(N) / N), np.zeros(N)], 1)


def cone(apex_z: float, extra: dict[int, float]) -> trimesh.Trimesh:
    """A fan from (0, 0, apex_z) to the loop, with a border vertex added at fraction t of segment k for each
    {k: t}; oriented outwards."""
    ring = []
    for k in range(N):
        ring.append(LOOP[k])
        if k in extra:
            ring.append(LOOP[k] + extra[k] * (LOOP[(k + 1) % N] - LOOP[k]))
    ring = np.asarray(ring)
    verts = np.concatenate([ring, [[0.0, 0.0, apex_z]]])
    m = len(ring)
    faces = np.stack([np.arange(m), (np.arange(m) + 1) % m, np.full(m, m)], 1)
    mesh = trimesh.Trimesh(verts, faces if apex_z > 0 else faces[:, ::-1], process=False)
    return mesh


def two_cones():
    upper = cone(1.0, {k: 0.5 for k in range(6)})
    lower = cone(-0.7, {k: 1 / 3 for k in range(3, 9)})
    return upper, lower


def test_two_cones_stitch_into_one_closed_surface_along_the_loop():
    upper, lower = two_cones()
    stitched = stitch_parts({"upper": upper, "lower": lower}, [SharedLoop("rim", ("upper", "lower"), LOOP)])
    mesh = stitched.mesh
    assert stitched.border_edges == 0 and stitched.open_loops == {}
    assert stitched.topology.describe() == "a connected surface (genus 0, 0 border loops, χ = 2)"
    assert consistently_oriented(np.asarray(mesh.faces))
    # splitting triangles at points of their edges changes neither the area nor the enclosed volume
    assert mesh.area == pytest.approx(upper.area + lower.area, rel=1e-12)
    cone_volume = trimesh.Trimesh(*_polygon_cone(1.0)).volume + trimesh.Trimesh(*_polygon_cone(0.7)).volume
    assert abs(mesh.volume) == pytest.approx(cone_volume, rel=1e-12)
    # the seam: the 12 loop vertices, the upper's 6 midpoints and the lower's 6 third-points, once each, on the loop
    seam = stitched.seams["rim"]
    assert len(seam) == 24
    _, dist = loop_parameter(np.asarray(mesh.vertices)[seam], LOOP)
    assert dist.max() < 1e-15
    for j in range(2):  # both parts' faces use every seam vertex
        assert set(seam) <= set(np.unique(np.asarray(mesh.faces)[stitched.face_part == j]))


def _polygon_cone(height: float):
    """The cone over the plain 12-gon (no extra border vertices), closed by the polygon: its volume is the reference."""
    verts = np.concatenate([LOOP, [[0, 0, height], [0, 0, 0]]])
    side = np.stack([np.arange(N), (np.arange(N) + 1) % N, np.full(N, N)], 1)
    base = np.stack([(np.arange(N) + 1) % N, np.arange(N), np.full(N, N + 1)], 1)
    return verts, np.concatenate([side, base])


def test_a_part_facing_against_its_target_is_flipped():
    upper, lower = two_cones()
    backwards = trimesh.Trimesh(lower.vertices, np.asarray(lower.faces)[:, ::-1], process=False)
    stitched = stitch_parts({"upper": upper, "lower": backwards}, [SharedLoop("rim", ("upper", "lower"), LOOP)],
                            targets={"upper": upper, "lower": lower})
    assert stitched.flipped == ["lower"]
    assert consistently_oriented(np.asarray(stitched.mesh.faces)) and stitched.border_edges == 0


def test_a_loop_with_one_side_stays_open():
    upper, _ = two_cones()
    far = cone(-0.7, {})
    far.vertices = np.asarray(far.vertices) + [0.0, 0.0, -0.5]  # its border is off the loop
    stitched = stitch_parts({"upper": upper, "lower": far}, [SharedLoop("rim", ("upper", "lower"), LOOP)])
    assert "lower has no border along it" in stitched.open_loops["rim"]
    assert stitched.border_edges == 18 + 12  # both cones' own borders
