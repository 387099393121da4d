"""Speed of the Fig. 4 grid solver (Wang & Chern 2021 by ADMM, deepcurrents.baselines.grid_solver):
ADMM iterations per second at 64³ and 90³ (float64, the default, and float32), the share of the φ-step
(the cosine-transform Poisson solve), and the one-off cost of sampling α at the corners (trefoil).

    python benchmarks/grid_solver.py [--resolutions 64 90] [--iterations 20] [--repeats 3] [--device cpu|cuda]
                                     [--threads N]

Medians over repeats (the machine is shared and noisy). Prints a table and saves JSON under
benchmarks/results/grid_solver.json.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import time
from pathlib import Path

import torch

from deepcurrents.baselines.grid_solver import (
    GridProblem,
    admm_init,
    admm_step,
    cap_singularity,
    grid_spacing,
    grid_vertices,
)
from deepcurrents.geometry import biot_savart, trefoil

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_args import check_device, check_range  # noqa: E402  (a sibling module, not a package)


def sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize()


def corner_alpha(n: int, device: torch.device, dtype: torch.dtype) -> tuple[torch.Tensor, float]:
    """The trefoil's α at the (N+1)³ corners, scaled and capped as the model does; and its seconds."""
    sync(device)
    start = time.perf_counter()
    loops = [torch.tensor(lp, device=device, dtype=dtype) for lp in trefoil()]
    alpha = biot_savart(grid_vertices(n, device, dtype).reshape(-1, 3), loops).T.reshape(3, n + 1, n + 1, n + 1)
    alpha = 1e-3 * cap_singularity(alpha, grid_spacing(n))
    sync(device)
    return alpha, time.perf_counter() - start


def measure(alpha: torch.Tensor, iterations: int, repeats: int) -> dict[str, float]:
    device = alpha.device
    n = alpha.shape[1] - 1
    problem = GridProblem.from_alpha(alpha)
    state = admm_init(problem, rho=0.5 * grid_spacing(n) / 1e-3)
    for _ in range(3):  # warm-up (allocator, FFT plans)
        admm_step(problem, state, relaxation=1.6)
    per_iteration, poisson = [], []
    for _ in range(repeats):
        sync(device)
        start = time.perf_counter()
        for _ in range(iterations):
            admm_step(problem, state, relaxation=1.6)
        sync(device)
        per_iteration.append((time.perf_counter() - start) / iterations)
        sync(device)
        start = time.perf_counter()
        for _ in range(iterations):
            problem.least_squares(state.z)
        sync(device)
        poisson.append((time.perf_counter() - start) / iterations)
    t, p = statistics.median(per_iteration), statistics.median(poisson)
    return {"seconds_per_iteration": t, "iterations_per_second": 1.0 / t, "phi_step_seconds": p,
            "phi_step_share": p / t}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--resolutions", type=int, nargs="+", default=[64, 90])
    parser.add_argument("--iterations", type=int, default=20)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's)")
    args = parser.parse_args()
    check_range(parser, "--resolutions", args.resolutions, 4)  # the grid method's own least (model.grid.resolution)
    for flag, value in (("--iterations", args.iterations), ("--repeats", args.repeats), ("--threads", args.threads)):
        check_range(parser, flag, value, 1)
    device = check_device(parser, args.device)
    if args.threads:
        torch.set_num_threads(args.threads)
    rows = []
    for n in args.resolutions:
        alpha64, setup = corner_alpha(n, device, torch.float64)
        for dtype in (torch.float64, torch.float32):
            row = {"resolution": n, "dtype": str(dtype).removeprefix("torch."), "alpha_setup_seconds": setup,
                   **measure(alpha64.to(dtype), args.iterations, args.repeats)}
            rows.append(row)
            print(f"{n:4d}³ {row['dtype']:8s} {row['iterations_per_second']:8.2f} it/s "
                  f"({row['seconds_per_iteration'] * 1e3:8.1f} ms; φ-step {100 * row['phi_step_share']:4.0f}%)  "
                  f"α setup {setup:6.1f} s", flush=True)
    result = {
        "device": torch.cuda.get_device_name(device) if device.type == "cuda" else platform.processor() or "cpu",
        "threads": torch.get_num_threads(), "torch": torch.__version__, "iterations": args.iterations,
        "repeats": args.repeats, "rows": rows,
    }
    out = Path(__file__).parent / "results"
    out.mkdir(parents=True, exist_ok=True)
    (out / "grid_solver.json").write_text(json.dumps(result, indent=2))
    print(f"saved {out / 'grid_solver.json'}")


if __name__ == "__main__":
    main()
