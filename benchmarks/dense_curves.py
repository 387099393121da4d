"""Dense curves: what a curve's vertex count costs, and what resampling it by arc length costs in accuracy.

1. Time of α_Γ (Biot–Savart) for one training batch of 4096 points against the loop's vertex count
   (100, 1k, 10k, 200k), for the closed form before this change (every point–segment pair as (N, S, 3)
   tensors, kept here as the reference) and the current one (deepcurrents.geometry.biot_savart: (N, S)
   matrices and matrix products), side by side in one run; beside them the time of one training step of the
   network alone (forward and the double backward, α excluded) at the same batch, for scale. Where a size
   would take long, fewer points are timed and the time is scaled to 4096 (the cost is linear in points).
2. Resampling (deepcurrents.geometry.polyline.resample_loop, the default data.max_vertices_per_loop=512):
   a circle of radius 0.5 given with 200,000 vertices, resampled to 512/256/128: the area of its minimal
   surface (the flat polygon, exact) against the original's and the circle's, and how much α changes
   (relative RMS difference at 1024 points at least 0.05 from Γ); the same α change for Enneper's curve.

    python benchmarks/dense_curves.py [--vertices 100 1000 10000 200000] [--repeats 3]

Prints tables and saves benchmarks/results/dense_curves.json.
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np
import torch

from deepcurrents.geometry import biot_savart, circle, solid_angle
from deepcurrents.geometry.curves import enneper
from deepcurrents.geometry.polyline import resample_loop
from deepcurrents.nn import neural_current

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_args import check_range  # noqa: E402  (a sibling module, not a package)

BATCH = 4096


def biot_savart_before(points: torch.Tensor, loops: list[torch.Tensor]) -> torch.Tensor:
    """The closed form as it was before this change (reference for timing): (N, S, 3) tensors per chunk."""
    starts = torch.cat(loops)
    ends = torch.cat([torch.roll(lp, -1, 0) for lp in loops])
    chunk = max(1024, (1 << 24) // starts.shape[0])
    out = []
    for p in torch.split(points, chunk):
        seg = ends - starts
        t = seg / seg.norm(dim=-1, keepdim=True)
        r0 = starts.unsqueeze(0) - p.unsqueeze(1)
        r1 = ends.unsqueeze(0) - p.unsqueeze(1)
        cross = torch.linalg.cross(t.expand_as(r0), r0, dim=-1)
        cross_sq = (cross * cross).sum(-1)
        safe = cross_sq > 1e-12
        r0n = r0.norm(dim=-1).clamp_min(1e-30)
        r1n = r1.norm(dim=-1).clamp_min(1e-30)
        coef = (t * (r1 / r1n.unsqueeze(-1) - r0 / r0n.unsqueeze(-1))).sum(-1)
        denom = torch.where(safe, cross_sq, torch.ones_like(cross_sq))
        weight = torch.where(safe, coef / denom, torch.zeros_like(coef))
        out.append((weight.unsqueeze(-1) * cross).sum(1))
    return torch.cat(out)


def solid_angle_before(points: torch.Tensor, loops: list[torch.Tensor]) -> torch.Tensor:
    """Ω_Γ as it was before this change (reference for timing): (N, M, 3) tensors, a rolled copy, a cross."""
    total = torch.zeros(points.shape[0], dtype=points.dtype)
    for loop in loops:
        a = (loop.mean(0) - points).unsqueeze(1)
        b = loop.unsqueeze(0) - points.unsqueeze(1)
        d = torch.roll(b, shifts=-1, dims=1)
        an, bn, dn = a.norm(dim=-1), b.norm(dim=-1), d.norm(dim=-1)
        triple = (a * torch.linalg.cross(b, d, dim=-1)).sum(-1)
        denom = an * bn * dn + (a * b).sum(-1) * dn + (a * d).sum(-1) * bn + (b * d).sum(-1) * an
        total = total - 2.0 * torch.atan2(triple, denom).sum(1)
    return total


def timed(fn, repeats: int) -> float:
    fn()  # warm-up
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def alpha_times(sizes: list[int], repeats: int, max_pairs: float) -> list[dict]:
    gen = torch.Generator().manual_seed(0)
    rows = []
    for m in sizes:
        loop = [torch.as_tensor(circle(0.5, n=m), dtype=torch.float32)]
        n = int(min(BATCH, max(64, max_pairs // m)))
        pts = torch.rand(n, 3, generator=gen) * 2 - 1
        old = timed(lambda: biot_savart_before(pts, loop), repeats) * BATCH / n  # noqa: B023
        new = timed(lambda: biot_savart(pts, loop), repeats) * BATCH / n  # noqa: B023
        ref = biot_savart_before(pts, loop)
        err = float((biot_savart(pts, loop) - ref).norm() / ref.norm())
        # Ω (float64, as the phase meshing evaluates it), where the cost per pair was worst
        p64, l64 = pts.double()[: max(64, n // 4)], [loop[0].double()]
        om_old = timed(lambda: solid_angle_before(p64, l64), repeats) * BATCH / len(p64)  # noqa: B023
        om_new = timed(lambda: solid_angle(p64, l64), repeats) * BATCH / len(p64)  # noqa: B023
        om_err = float((solid_angle(p64, l64) - solid_angle_before(p64, l64)).abs().max())
        rows.append({"vertices": m, "points_timed": n, "before_seconds": old, "now_seconds": new,
                     "speedup": old / new, "relative_difference": err, "solid_angle_before_seconds": om_old,
                     "solid_angle_now_seconds": om_new, "solid_angle_max_difference": om_err})
        print(f"{m:7d} vertices: α for {BATCH} points {old * 1e3:9.1f} ms before, {new * 1e3:9.1f} ms now "
              f"(×{old / new:4.1f}; timed on {n} points; results differ by {err:.1e}); Ω (float64) "
              f"{om_old * 1e3:9.1f} ms before, {om_new * 1e3:9.1f} ms now (×{om_old / om_new:4.1f}, "
              f"max difference {om_err:.1e})", flush=True)
    return rows


def network_step_seconds(repeats: int) -> float:
    """One training step of preset=cpu's network (RFF 256, width 128, depth 3) without α, for scale."""
    current = neural_current(3, loops=[torch.as_tensor(circle(0.5, n=3), dtype=torch.float32)], num_frequencies=256,
                            width=128, depth=3)
    current.alpha = lambda x: torch.zeros_like(x)  # the network's share only
    opt = torch.optim.Adam(current.parameters(), lr=1e-3)
    x = torch.rand(BATCH, 3) * 2 - 1

    def step():
        opt.zero_grad()
        _, omega = current(x, create_graph=True)
        omega.norm(dim=-1).mean().backward()
        opt.step()

    return timed(step, repeats)


def probe_points(dense: np.ndarray, count: int = 1024, seed: int = 0) -> torch.Tensor:
    """``count`` uniform points of [-1, 1]³ at least 0.05 from a densely sampled curve. → (count, 3) float64."""
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(seed)
    pts = rng.uniform(-1, 1, (8 * count, 3))
    far = cKDTree(dense).query(pts)[0] > 0.05  # the vertices are 2e-5 apart: their distance is Γ's
    return torch.as_tensor(pts[far][:count])


def alpha_change(probes: torch.Tensor, original_alpha: torch.Tensor, resampled: np.ndarray) -> float:
    """Relative RMS difference of α at ``probes`` between the original curve and the resampled one."""
    b = biot_savart(probes, [torch.as_tensor(resampled)])
    return float((original_alpha - b).norm() / original_alpha.norm())


def polygon_area(loop: np.ndarray) -> float:
    """Area of a planar polygon (its minimal surface): half the norm of Σ v_i × v_{i+1}."""
    return float(0.5 * np.linalg.norm(np.cross(loop, np.roll(loop, -1, 0)).sum(0)))


def resampling_errors(targets: list[int]) -> list[dict]:
    dense = circle(0.5, normal=(1.0, 2.0, 2.0), n=200_000)
    exact, dense_area = math.pi * 0.25, polygon_area(dense)
    smooth = enneper(200_000)[0]
    probes = {"circle": probe_points(dense), "enneper": probe_points(smooth)}
    alpha = {"circle": biot_savart(probes["circle"], [torch.as_tensor(dense)]),
             "enneper": biot_savart(probes["enneper"], [torch.as_tensor(smooth)])}
    rows = []
    for n in targets:
        res = resample_loop(dense, n)
        area = polygon_area(res)
        row = {"vertices": n, "circle_area": area, "circle_area_error_vs_200k": area / dense_area - 1,
               "circle_area_error_vs_exact": area / exact - 1,
               "circle_alpha_change": alpha_change(probes["circle"], alpha["circle"], res),
               "enneper_alpha_change": alpha_change(probes["enneper"], alpha["enneper"], resample_loop(smooth, n))}
        rows.append(row)
        print(f"200,000 → {n:4d} vertices: disk area {row['circle_area_error_vs_200k']:+.2e} vs the 200k-gon "
              f"({row['circle_area_error_vs_exact']:+.2e} vs πR²); α changes by {row['circle_alpha_change']:.1e} "
              f"(circle), {row['enneper_alpha_change']:.1e} (Enneper) off Γ", flush=True)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--vertices", type=int, nargs="+", default=[100, 1000, 10_000, 200_000])
    parser.add_argument("--resampled", type=int, nargs="+", default=[512, 256, 128])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--max-pairs", type=float, default=4e7, help="point–segment pairs timed per call at most")
    args = parser.parse_args()
    check_range(parser, "--vertices", args.vertices, 3)  # a loop needs three vertices
    check_range(parser, "--resampled", args.resampled, 3)
    check_range(parser, "--repeats", args.repeats, 1)
    check_range(parser, "--max-pairs", args.max_pairs, 1)
    step = network_step_seconds(args.repeats)
    print(f"network step (preset=cpu sizes, {BATCH} points, α excluded): {step * 1e3:.1f} ms", flush=True)
    rows = alpha_times(args.vertices, args.repeats, args.max_pairs)
    resampled = resampling_errors(args.resampled)
    result = {"machine": platform.processor() or platform.machine(), "threads": torch.get_num_threads(),
              "torch": torch.__version__, "loadavg": Path("/proc/loadavg").read_text().split()[:3]
              if Path("/proc/loadavg").exists() else None,
              "batch": BATCH, "network_step_seconds": step, "alpha": rows, "resampling": resampled}
    out = Path(__file__).parent / "results"
    out.mkdir(parents=True, exist_ok=True)
    (out / "dense_curves.json").write_text(json.dumps(result, indent=2))
    print(f"saved {out / 'dense_curves.json'}")


if __name__ == "__main__":
    main()
