"""How much of a CPU reconstruction step goes to closest-point queries (issue: they must not dominate).

For a human-part target (default: the first generated hand, else a spherical cap) it times, in one run,
with medians over repeats:
  - the closest points of the ambient samples on Σ (libigl AABB) and on Γ (boundary weighting),
  - a whole batch of the DataModule (metric, weights, surface samples),
  - one training step (forward, double backward, Adam) of the CPU preset's network and of the paper's,
and prints and saves the shares to benchmarks/results/closest_points.json.

    python benchmarks/closest_points.py [--mesh data/anny/hands/000.ply] [--samples 4000] [--repeats 7]
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import numpy as np
import torch
import trimesh

from deepcurrents.data.recon import read_target_mesh
from deepcurrents.data.targets import MeshTarget, distance_to_loops
from deepcurrents.losses import current_loss, surface_loss
from deepcurrents.nn import neural_current

NETS = {
    "cpu_preset": {"num_frequencies": 256, "width": 128, "depth": 3},
    "paper": {"num_frequencies": 1024, "width": 256, "depth": 4},
}


def median_time(fn, repeats: int) -> float:
    fn()  # warm-up
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--mesh", default="data/anny/hands/000.ply")
    parser.add_argument("--samples", type=int, default=4000)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--out", default="benchmarks/results/closest_points.json")
    args = parser.parse_args()
    torch.manual_seed(0)
    if Path(args.mesh).is_file():
        verts, faces = read_target_mesh(args.mesh)
        name = args.mesh
    else:  # no dataset: a spherical cap of similar size
        sphere = trimesh.creation.icosphere(4, radius=0.5)
        keep = sphere.triangles_center[:, 2] > 0.1
        cap = trimesh.Trimesh(sphere.vertices, sphere.faces[keep])
        cap.remove_unreferenced_vertices()
        verts, faces, name = np.asarray(cap.vertices), np.asarray(cap.faces), "spherical cap (icosphere 4)"
    target = MeshTarget(verts, faces)
    n = args.samples
    gen = torch.Generator().manual_seed(0)
    x = (torch.rand(n, 3, generator=gen, dtype=torch.float64) * 2 - 1).numpy()
    batch = target.sample(n, n, gen)

    results = {"target": name, "faces": int(len(faces)), "gamma_vertices": int(sum(map(len, target.loops))),
               "samples": n, "threads": torch.get_num_threads()}
    results["closest_on_sigma_s"] = median_time(lambda: target.closest(x), args.repeats)
    results["closest_on_gamma_s"] = median_time(lambda: distance_to_loops(x[: n // 2], target.loops),
                                                args.repeats)
    results["whole_batch_s"] = median_time(lambda: target.sample(n, n, gen), args.repeats)
    results["tree_build_s"] = median_time(lambda: MeshTarget(verts, faces), args.repeats)

    for key, net in NETS.items():
        loops = [torch.as_tensor(lp, dtype=torch.float32) for lp in target.loops]
        current = neural_current(3, loops=loops, **net)
        opt = torch.optim.Adam(current.parameters(), lr=1e-3)

        def step(current=current, opt=opt):
            _, omega = current(batch["x"], create_graph=True)
            off = batch["epsilon"][:, None] * batch["surface_normals"]
            y = batch["surface_points"]
            fm, fp = current.f(torch.cat([y - off, y + off])).chunk(2)
            loss = current_loss(omega, batch["metric"]) + surface_loss(fm, fp)
            opt.zero_grad()
            loss.backward()
            opt.step()

        t_step = median_time(step, max(3, args.repeats // 2))
        queries = results["closest_on_sigma_s"] + results["closest_on_gamma_s"]
        results[f"step_{key}_s"] = t_step
        # share if the batch were made in the training process; with num_workers ≥ 1 it overlaps the step
        results[f"closest_share_of_step_{key}"] = queries / (queries + t_step)
        results[f"batch_share_of_step_{key}"] = results["whole_batch_s"] / (results["whole_batch_s"] + t_step)

    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(results, indent=2))
    for key, value in results.items():
        print(f"{key:36s} {value:.4g}" if isinstance(value, float) else f"{key:36s} {value}")
    print(f"saved {out}")


if __name__ == "__main__":
    main()
