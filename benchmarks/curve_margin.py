"""How far from the box's wall must a curve stay? The converged grid current (Wang & Chern, the solver of
deepcurrents.baselines.grid_solver) of Enneper's curve (parameter radius 0.8, exact minimal area known)
scaled so that its largest |coordinate| is m, for several m.

The box U = [-1, 1]³ is part of the problem: f (here φ) is free on ∂U, so a current may end on the wall
instead of spanning Γ, and the problem solved is Plateau's only if no such current is cheaper. The grid
solves that box problem to convergence (with a certified lower bound), so the ratio to the exact area at each
m shows the wall's effect alone. The resolution grows as 1/m so that the curve always spans the same number
of cells: the discretisation's own O(h) excess is then the same at every m and cancels in the comparison.

    python benchmarks/curve_margin.py [--curve enneper|hopf] [--extents 0.95 0.85 0.7 0.6 0.5] [--cells 40]

Prints a table and saves JSON under benchmarks/results/curve_margin_<curve>.json. The README quotes
``--cells 24 --extents 0.9 0.8 0.7 0.65 0.6 0.55 0.5 0.45 0.4`` (Enneper) and ``--curve hopf --extents 0.9 0.5``.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
import torch

from deepcurrents.baselines.grid_solver import (
    GridProblem,
    admm_init,
    admm_step,
    cap_singularity,
    grid_spacing,
    grid_vertices,
)
from deepcurrents.geometry import biot_savart
from deepcurrents.geometry.curves import enneper, enneper_area, hopf_link

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_args import check_range  # noqa: E402  (a sibling module, not a package)

ALPHA_SCALE = 1e-3


def solve(loops: list[np.ndarray], n: int, iterations: int, tol: float) -> dict[str, float]:
    """The box problem's mass at the grid optimum, as an area, with its certified lower bound."""
    h = grid_spacing(n)
    corners = grid_vertices(n, dtype=torch.float64).reshape(-1, 3)
    alpha = biot_savart(corners, [torch.as_tensor(lp) for lp in loops]).T.reshape(3, n + 1, n + 1, n + 1)
    problem = GridProblem.from_alpha(ALPHA_SCALE * cap_singularity(alpha, h))
    state = admm_init(problem, rho=0.5 * h / ALPHA_SCALE)
    report = None
    for _ in range(iterations):
        report = admm_step(problem, state, relaxation=1.6)
        if state.iteration >= 10 and max(report.primal, report.dual) < tol:
            break
    to_area = 1.0 / (4.0 * math.pi * ALPHA_SCALE)
    return {"area": report.mass * to_area, "area_lower": problem.dual_bound(state.rho * state.u) * to_area,
            "iterations": state.iteration, "primal": report.primal, "dual": report.dual}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--extents", type=float, nargs="+", default=[0.95, 0.85, 0.7, 0.6, 0.5])
    parser.add_argument("--cells", type=int, default=40, help="grid cells across the curve's largest extent")
    parser.add_argument("--iterations", type=int, default=400)
    parser.add_argument("--tol", type=float, default=1e-3)
    parser.add_argument("--vertices", type=int, default=200)
    parser.add_argument("--curve", default="enneper", choices=["enneper", "hopf"],
                        help="hopf (the paper's Hopf link) has no exact area: its ratio is to the last extent's area")
    args = parser.parse_args()
    check_range(parser, "--extents", args.extents, 0.0, 1.0, above=True, below=True,
                why="the curve's largest |coordinate|, inside the box [-1, 1]³")
    check_range(parser, "--cells", args.cells, 1)
    check_range(parser, "--iterations", args.iterations, 1)
    check_range(parser, "--tol", args.tol, 0.0, above=True)
    check_range(parser, "--vertices", args.vertices, 3)  # a loop needs three vertices
    base = enneper(args.vertices, 0.8) if args.curve == "enneper" else hopf_link(args.vertices)
    base_extent = max(float(np.abs(lp).max()) for lp in base)
    reference = None
    if args.curve == "hopf":  # the far-inside solution, in the curve's own units, stands for the exact area
        k = args.extents[-1] / base_extent
        reference = solve([lp * k for lp in base], max(8, round(args.cells / args.extents[-1])), args.iterations,
                          args.tol)["area"] / k**2
    rows = []
    for m in args.extents:
        k = m / base_extent
        loop = [lp * k for lp in base]
        exact = (enneper_area(0.8) if reference is None else reference) * k * k
        # the curve spans `cells` cells of its largest extent 2m: h = 2m / cells, N = 2 / h
        n = max(8, round(args.cells / m))
        start = time.perf_counter()
        res = solve(loop, n, args.iterations, args.tol)
        row = {"extent": m, "euclidean_radius": max(float(np.linalg.norm(lp, axis=1).max()) for lp in loop),
               "resolution": n,
               "exact": exact, **res, "ratio": res["area"] / exact, "ratio_lower": res["area_lower"] / exact,
               "seconds": time.perf_counter() - start}
        rows.append(row)
        print(f"max|x|={m:4.2f} (|x|≤{row['euclidean_radius']:.2f}) N={n:3d}: grid area/exact {row['ratio']:.4f} "
              f"(certified ≥ {row['ratio_lower']:.4f}), {res['iterations']} it, {row['seconds']:.0f} s", flush=True)
    out = Path(__file__).parent / "results"
    out.mkdir(parents=True, exist_ok=True)
    result = {"curve": args.curve, "cells": args.cells, "threads": torch.get_num_threads(), "rows": rows}
    (out / f"curve_margin_{args.curve}.json").write_text(json.dumps(result, indent=2))
    print(f"saved {out / f'curve_margin_{args.curve}.json'}")


if __name__ == "__main__":
    main()
