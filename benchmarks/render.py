"""Volume rendering cost: how much of a render is the evaluation of ω itself, and seconds per image at the
render app's presets, for the CPU-preset network on the trefoil.

    python benchmarks/render.py [--device cpu|cuda] [--repeats 3] [--preset cpu|gpu]

A render evaluates ω at (rays that meet the support) × samples points, plus the proposal grid's nodes; the
rest (ray set-up, proposal look-ups, quantile sampling, compositing, Γ's overlay) is the renderer's own
overhead. Both are timed in the same run (medians of ``--repeats``) and their ratio printed. The network is
untrained (deterministic seed), so its support is the whole domain: the worst case for the number of rays.
Prints a table and saves JSON under benchmarks/results/.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import time
from pathlib import Path

import torch

from deepcurrents.cli.render import PRESETS
from deepcurrents.eval.render import (
    DensitySettings,
    fit_camera,
    proposal_grid,
    render_current,
)
from deepcurrents.eval.render.volume import _box_intersection
from deepcurrents.geometry import trefoil
from deepcurrents.nn import neural_current


def sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize()


def timed(fn, device, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        sync(device)
        start = time.perf_counter()
        fn()
        sync(device)
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    parser.add_argument("--preset", default="cpu", choices=sorted(PRESETS))
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    device = torch.device(args.device)
    preset = PRESETS[args.preset]
    torch.manual_seed(0)
    loops = [torch.as_tensor(lp, dtype=torch.float32) for lp in trefoil(100)]
    # the CPU preset's network (conf/preset/cpu.yaml)
    current = neural_current(3, loops=loops, num_frequencies=256, width=128, depth=3, rff_seed=0).to(device).eval()
    settings = DensitySettings()

    grid_s = timed(lambda: proposal_grid(current, preset["grid"], settings), device, args.repeats)
    grid = proposal_grid(current, preset["grid"], settings)
    camera = fit_camera(grid.framing_points(), width=preset["size"], height=preset["size"])
    render_s = timed(lambda: render_current(current, camera, samples=preset["samples"], grid=grid,
                                            settings=settings), device, args.repeats)
    origins, dirs = camera.rays(device)
    hits = int(_box_intersection(origins, dirs, grid.support)[2].sum())
    points = hits * preset["samples"]
    x = torch.rand(points, 3, device=device) * 2 - 1
    omega_s = timed(lambda: current.evaluate(x), device, args.repeats)
    result = {
        "device": str(device), "machine": platform.processor() or platform.machine(),
        "torch_threads": torch.get_num_threads(), "preset": args.preset, "size": preset["size"],
        "samples": preset["samples"], "grid": preset["grid"], "rays_hitting_support": hits,
        "omega_points": points, "proposal_grid_s": grid_s, "render_s": render_s,
        "omega_eval_s": omega_s, "omega_points_per_s": points / omega_s,
        "omega_share_of_render": omega_s / render_s, "repeats": args.repeats,
    }
    print(f"{'preset':>8} {'size':>5} {'samples':>7} {'rays hit':>9} {'grid s':>7} {'render s':>9} "
          f"{'ω only s':>9} {'ω share':>8}")
    print(f"{args.preset:>8} {preset['size']:>5} {preset['samples']:>7} {hits:>9} {grid_s:>7.2f} "
          f"{render_s:>9.2f} {omega_s:>9.2f} {omega_s / render_s:>8.0%}")
    out = Path(__file__).parent / "results"
    out.mkdir(exist_ok=True)
    path = out / f"render_{args.preset}_{device.type}.json"
    path.write_text(json.dumps(result, indent=2))
    print(f"saved {path}")


if __name__ == "__main__":
    main()
