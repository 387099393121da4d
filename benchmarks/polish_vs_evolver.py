"""Our polished minimal-surface areas against Brakke's Surface Evolver on the same topology, in one run.

    python benchmarks/polish_vs_evolver.py outputs/minimal_curve/RUN=2.4168785 outputs/minimal_trefoil/RUN ...
    python benchmarks/polish_vs_evolver.py RUN ... --levels 3 --edge-length 0.025 --out benchmarks/results/mine

Each argument is a trained minimal-surface run folder (``mesh.ply`` and ``checkpoints/last.ckpt``), optionally with
the exact area of the smooth curve after ``=``. For each run, from the same start (the run's extracted mesh with
its border snapped onto Γ and its interior remeshed to the polish's level-1 edges, ``eval.meshing.polish``):

- ours: ``polish_minimal_surface`` (Pinkall–Polthier's flow on each level, midpoint refinement, Richardson), timed;
- Surface Evolver (``evolver`` on the PATH, Debian's ``evolver-nox``; not a dependency of the package): the start
  written as a ``.fe`` file with Γ's vertices and edges ``fixed`` (refining a fixed edge puts its midpoint on Γ's
  segment, as ours), then on each level ``g 5; hessian_seek`` until the area changes by less than 1e-9 relatively,
  and ``r`` between levels; its areas extrapolated the same way. Without ``evolver`` that column is skipped, said.

Prints per run the finest area and the extrapolation of each, their relative difference, the seconds each took
and the ratio, and how long each needed to get within ``--accuracy`` of the reference (the mean of the two
extrapolations: both solve the same discrete problem, the surface spanning Γ's polyline). Writes
``polish_vs_evolver.json``, ``.csv`` and ``.md`` under ``--out``. Time only on an otherwise idle machine.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import platform
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_args import check_range  # noqa: E402

from deepcurrents.eval.meshing.polish import (  # noqa: E402
    PolishSettings,
    level_one_mesh,
    polish_minimal_surface,
    richardson,
)
from deepcurrents.geometry.topology import border_edges  # noqa: E402

# Surface Evolver's commands per level: gradient steps and a Newton step with line search until the area settles
EVOLVER_LEVEL = """kk := 0
aa := 0
do {{ aa := total_area; g 5; hessian_seek; kk := kk + 1 }} while (abs(aa - total_area) > {tol}*total_area and kk < 50)
printf "LEVEL %.17g %.6f %d %d\\n", total_area, clock, facet_count, kk
"""


def write_fe(path: Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    """A Surface Evolver datafile of a triangle mesh: vertices, edges (signed, oriented) and facets; the border's
    vertices and edges ``fixed``."""
    fixed_edges = {tuple(e) for e in np.sort(border_edges(faces), 1).tolist()}
    fixed = {v for e in fixed_edges for v in e}
    index: dict[tuple[int, int], int] = {}
    facet_edges = []
    for face in faces.tolist():
        signed = []
        for a, b in ((face[0], face[1]), (face[1], face[2]), (face[2], face[0])):
            key = (min(a, b), max(a, b))
            if key not in index:
                index[key] = len(index) + 1
            signed.append(index[key] if a < b else -index[key])
        facet_edges.append(signed)
    lines = ["vertices"]
    lines += [f"{i + 1} {x:.17g} {y:.17g} {z:.17g}{' fixed' if i in fixed else ''}"
              for i, (x, y, z) in enumerate(vertices.tolist())]
    lines += ["", "edges"]
    lines += [f"{k} {a + 1} {b + 1}{' fixed' if (a, b) in fixed_edges else ''}" for (a, b), k in index.items()]
    lines += ["", "faces"]
    lines += [f"{i + 1} {e[0]} {e[1]} {e[2]}" for i, e in enumerate(facet_edges)]
    path.write_text("\n".join(lines) + "\n")


def run_evolver(evolver: str, vertices: np.ndarray, faces: np.ndarray, levels: int, tolerance: float,
                timeout: float) -> dict:
    """Surface Evolver from a mesh: its area, clock and facets at the end of each level. → {"areas", "seconds",
    "facets", "wall_seconds"} (seconds: Evolver's clock, from its start), or {"error": ...}."""
    with tempfile.TemporaryDirectory() as tmp:
        fe, commands = Path(tmp) / "start.fe", Path(tmp) / "polish.cmd"
        write_fe(fe, vertices, faces)
        level = EVOLVER_LEVEL.format(tol=f"{tolerance:g}")
        commands.write_text(level + "".join("r\n" + level for _ in range(levels - 1)) + "q\nq\n")
        began = time.perf_counter()
        try:
            out = subprocess.run([evolver, "-x", "-f", str(commands), str(fe)], capture_output=True, text=True,
                                 timeout=timeout, stdin=subprocess.DEVNULL)
        except subprocess.TimeoutExpired:
            return {"error": f"Surface Evolver took more than {timeout:g} s"}
        wall = time.perf_counter() - began
    found = re.findall(r"^LEVEL (\S+) (\S+) (\d+) (\d+)", out.stdout, flags=re.M)
    if len(found) < levels:
        tail = (out.stdout + out.stderr).strip().splitlines()[-3:]
        return {"error": f"Surface Evolver stopped after {len(found)} of {levels} levels: {' / '.join(tail)}"}
    return {"areas": [float(a) for a, _, _, _ in found], "seconds": [float(c) for _, c, _, _ in found],
            "facets": [int(f) for _, _, f, _ in found], "iterations": [int(k) for _, _, _, k in found],
            "wall_seconds": wall}


def time_to(areas: list[float], seconds: list[float], reference: float, accuracy: float) -> float | None:
    """The seconds at the end of the first level whose area, or the Richardson value up to it, is within
    ``accuracy`` of ``reference`` (relative); None if none is."""
    for k in range(len(areas)):
        candidates = [areas[k]] + ([richardson(areas[: k + 1])[0]] if k else [])
        if any(abs(c / reference - 1.0) <= accuracy for c in candidates):
            return seconds[k]
    return None


def run_boundary(run_dir: Path) -> list[np.ndarray]:
    """Γ of a run in its mesh.ply's units (float64, as the run read it)."""
    import deepcurrents as dc

    return [np.asarray(lp, np.float64) for lp in dc.load(run_dir).boundary]


def compare(run_dir: Path, exact: float | None, settings: PolishSettings, evolver: str | None, accuracy: float,
            timeout: float) -> dict:
    """One run: ours and Surface Evolver's areas, seconds and their ratios (module docstring)."""
    mesh = trimesh.load(run_dir / "mesh.ply", process=False)
    loops = run_boundary(run_dir)
    row: dict = {"run": str(run_dir), "exact": exact, "extracted_area": float(mesh.area),
                 "extracted_faces": int(len(mesh.faces))}
    ours = polish_minimal_surface(mesh, loops, settings)
    if ours.stopped:
        return {**row, "error": f"not polished: {ours.stopped}"}
    row.update(surface=ours.topology.describe(), ours_areas=ours.areas, ours_extrapolated=ours.extrapolated,
               ours_extrapolated_error=ours.extrapolated_error, ours_smooth_curve=ours.curve_extrapolated,
               ours_seconds=ours.seconds, ours_level_seconds=ours.level_seconds, ours_faces=len(ours.mesh.faces))
    start = level_one_mesh(mesh, loops, settings)  # what Surface Evolver starts from: the flow's start
    if evolver is None:
        row["evolver"] = "not on the PATH (apt-get install evolver-nox)"
    else:
        se = run_evolver(evolver, start.vertices, start.faces, settings.levels, 1e-9, timeout)
        if "error" in se:
            row["evolver"] = se["error"]
        else:
            se_value, se_error = richardson(se["areas"])
            row.update(evolver_areas=se["areas"], evolver_extrapolated=se_value, evolver_extrapolated_error=se_error,
                       evolver_seconds=se["seconds"][-1], evolver_level_seconds=se["seconds"],
                       evolver_facets=se["facets"][-1], evolver_iterations=se["iterations"])
            reference = 0.5 * (se_value + ours.extrapolated)
            row.update(relative_difference=ours.extrapolated / se_value - 1.0,
                       finest_relative_difference=ours.areas[-1] / se["areas"][-1] - 1.0,
                       seconds_ratio=se["seconds"][-1] / ours.seconds,
                       ours_seconds_to_accuracy=time_to(ours.areas, ours.level_seconds, reference, accuracy),
                       evolver_seconds_to_accuracy=time_to(se["areas"], se["seconds"], reference, accuracy))
    if exact:
        row.update(ours_extrapolated_vs_exact=ours.extrapolated / exact - 1.0,
                   ours_smooth_curve_vs_exact=(ours.curve_extrapolated / exact - 1.0
                                               if ours.curve_extrapolated is not None else None))
        if row.get("evolver_extrapolated"):
            row["evolver_extrapolated_vs_exact"] = row["evolver_extrapolated"] / exact - 1.0
    return row


def say(row: dict) -> str:
    """One run's lines for the terminal."""
    if "error" in row:
        return f"{row['run']}: {row['error']}"
    lines = [f"{row['run']}: {row['surface']}",
             f"  ours:    finest {row['ours_areas'][-1]:.8f}  extrapolated {row['ours_extrapolated']:.8f} "
             f"± {row['ours_extrapolated_error']:.1e}  in {row['ours_seconds']:.2f} s"]
    if "evolver_areas" in row:
        lines.append(f"  Evolver: finest {row['evolver_areas'][-1]:.8f}  extrapolated {row['evolver_extrapolated']:.8f}"
                     f" ± {row['evolver_extrapolated_error']:.1e}  in {row['evolver_seconds']:.2f} s "
                     f"({row['evolver_facets']} facets)")
        t_ours, t_se = row["ours_seconds_to_accuracy"], row["evolver_seconds_to_accuracy"]
        reach = f"{t_se / t_ours:.1f}× ours" if t_ours and t_se else "not both reached"
        ours_s, se_s = (f"{t:.2f} s" if t is not None else "never" for t in (t_ours, t_se))
        lines.append(f"  extrapolations differ by {row['relative_difference']:+.1e}; Evolver's seconds / ours "
                     f"{row['seconds_ratio']:.1f}; to the accuracy: ours {ours_s}, Evolver {se_s} ({reach})")
    else:
        lines.append(f"  Evolver: {row.get('evolver')}")
    if row.get("exact"):
        smooth = row.get("ours_smooth_curve_vs_exact")
        lines.append(f"  vs the smooth curve's exact {row['exact']:.8f}: polyline extrapolation "
                     f"{row['ours_extrapolated_vs_exact']:+.1e}"
                     + (f", smooth-curve extrapolation {smooth:+.1e}" if smooth is not None else ""))
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", nargs="+", help="run folders, each optionally =EXACT_AREA of the smooth curve")
    ap.add_argument("--levels", type=int, default=PolishSettings.levels)
    ap.add_argument("--edge-length", type=float, default=PolishSettings.edge_length)
    ap.add_argument("--accuracy", type=float, default=1e-4, help="relative accuracy for the time-to-accuracy column")
    ap.add_argument("--evolver", default=shutil.which("evolver"), help="Surface Evolver's executable")
    ap.add_argument("--timeout", type=float, default=600.0, help="seconds Surface Evolver may take per run")
    ap.add_argument("--out", default="benchmarks/results/polish_vs_evolver")
    args = ap.parse_args()
    check_range(ap, "--levels", args.levels, 2, 6, why="two levels or more give the extrapolation")
    check_range(ap, "--edge-length", args.edge_length, 1e-3, 0.5)
    check_range(ap, "--accuracy", args.accuracy, 0, 1, above=True)
    runs = []
    for spec in args.runs:
        path, _, exact = spec.partition("=")
        if not (Path(path) / "mesh.ply").is_file():
            ap.error(f"{path} is not a minimal-surface run folder (it has no mesh.ply).")
        try:
            runs.append((Path(path), float(exact) if exact else None))
        except ValueError:
            ap.error(f"{spec}: the exact area after '=' must be a number.")
    if args.evolver is None:
        print("Surface Evolver is not on the PATH (apt-get install evolver-nox): its column is skipped.")
    settings = PolishSettings(edge_length=args.edge_length, levels=args.levels)
    rows = []
    for run_dir, exact in runs:
        row = compare(run_dir, exact, settings, args.evolver, args.accuracy, args.timeout)
        print(say(row), flush=True)
        rows.append(row)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    machine = {"platform": platform.platform(), "cpus": os.cpu_count(), "load": os.getloadavg(),
               "settings": vars(args)}
    (out / "polish_vs_evolver.json").write_text(json.dumps({"machine": machine, "runs": rows}, indent=2))
    scalar = sorted({k for r in rows for k, v in r.items() if not isinstance(v, list)})
    with open(out / "polish_vs_evolver.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=scalar, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)
    table = ["| run | surface | ours extrapolated | Evolver extrapolated | rel. diff. | ours s | Evolver s |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        if "error" in r:
            continue
        se = r.get("evolver_extrapolated")
        table.append(f"| {Path(r['run']).name} | {r['surface']} | {r['ours_extrapolated']:.8f} | "
                     f"{f'{se:.8f}' if se else '–'} | {r.get('relative_difference', float('nan')):+.1e} | "
                     f"{r['ours_seconds']:.2f} | {r.get('evolver_seconds', float('nan')):.2f} |")
    (out / "polish_vs_evolver.md").write_text("\n".join(table) + "\n")
    print(f"wrote {out}/polish_vs_evolver.json, .csv, .md")


if __name__ == "__main__":
    main()
