"""benchmarks/polish_vs_evolver.py: the Surface Evolver datafile it writes, Evolver's areas on a polygon whose
minimal area is known (where ``evolver`` is installed), and its refusals."""

from __future__ import annotations

import math
import shutil

import numpy as np
import pytest
from conftest import disk_mesh, load_benchmark, ring

from deepcurrents.geometry.topology import border_edges

bench = load_benchmark("polish_vs_evolver")


def dome(n=24, rows=4, bump=0.2):
    """A dome of triangles over the regular n-gon of radius 0.5 in z = 0. → (the n-gon, vertices, faces)."""
    loop = ring(0.5, 0.0, n)
    return (loop, *disk_mesh(loop, rows, bump))


def read_fe(path):
    """The sections of a datafile: vertices {id: (xyz, fixed)}, edges {id: (a, b, fixed)}, faces [[signed ids]]."""
    section, vertices, edges, faces = None, {}, {}, []
    for line in path.read_text().splitlines():
        words = line.split()
        if not words:
            continue
        if words[0] in ("vertices", "edges", "faces"):
            section = words[0]
        elif section == "vertices":
            vertices[int(words[0])] = (np.array(words[1:4], float), words[-1] == "fixed")
        elif section == "edges":
            edges[int(words[0])] = (int(words[1]), int(words[2]), words[-1] == "fixed")
        else:
            faces.append([int(w) for w in words[1:4]])
    return vertices, edges, faces


def test_the_datafile_has_the_mesh_with_its_border_fixed(tmp_path):
    loop, verts, faces = dome()
    bench.write_fe(tmp_path / "dome.fe", verts, faces)
    vertices, edges, facets = read_fe(tmp_path / "dome.fe")
    assert len(vertices) == len(verts) and len(facets) == len(faces) and len(edges) == 3 * len(faces) // 2 + 12
    border = set(np.unique(border_edges(faces)) + 1)
    assert {i for i, (_, fixed) in vertices.items() if fixed} == border
    assert sum(fixed for *_, fixed in edges.values()) == 24
    for facet, face in zip(facets, faces, strict=True):  # signed edges run head to tail around the face, in order
        walk = [edges[e][:2] if e > 0 else edges[-e][1::-1] for e in facet]
        assert [a - 1 for a, _ in walk] == list(face) and all(walk[k][1] == walk[(k + 1) % 3][0] for k in range(3))
    assert np.allclose(vertices[1][0], verts[0], rtol=0, atol=1e-15)


@pytest.mark.skipif(shutil.which("evolver") is None, reason="Surface Evolver (evolver-nox) is not installed")
def test_evolver_flattens_the_dome_onto_the_polygons_exact_area():
    _, verts, faces = dome()
    se = bench.run_evolver(shutil.which("evolver"), verts, faces, levels=2, tolerance=1e-12, timeout=60)
    exact = 24 / 2 * 0.25 * math.sin(2 * math.pi / 24)  # the regular 24-gon
    assert "error" not in se, se
    assert all(math.isclose(a, exact, rel_tol=1e-9) for a in se["areas"])
    assert se["facets"] == [len(faces), 4 * len(faces)]


@pytest.mark.parametrize(("argv", "sentence"), [
    (["--levels", "1", "x"], "--levels 1 must be in [2, 6] (two levels or more give the extrapolation)."),
    (["--edge-length", "0", "x"], "--edge-length 0.0 must be in [0.001, 0.5]."),
])
def test_refusals(monkeypatch, capsys, argv, sentence):
    monkeypatch.setattr("sys.argv", ["polish_vs_evolver.py", *argv])
    with pytest.raises(SystemExit) as info:
        bench.main()
    err = capsys.readouterr().err
    assert info.value.code == 2 and "Traceback" not in err and err.strip().splitlines()[-1].endswith(sentence), err


def test_a_folder_without_a_mesh_is_refused(monkeypatch, capsys, tmp_path):
    monkeypatch.setattr("sys.argv", ["polish_vs_evolver.py", str(tmp_path)])
    with pytest.raises(SystemExit) as info:
        bench.main()
    assert info.value.code == 2
    assert capsys.readouterr().err.strip().endswith(f"{tmp_path} is not a minimal-surface run folder (it has no "
                                                   "mesh.ply).")
