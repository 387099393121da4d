"""Families of surfaces: where the time of a training step goes, measured in one run.

    python benchmarks/family_step.py [--data data/anny/hands] [--meshes 8] [--samples 4000]
                                     [--paper | --cpu] [--repeats 7] [--device cpu|cuda] [--threads N]

1. data: one batch (per mesh: augmentation with harmonic skinning + reconstruction samples), in-process —
   what each DataLoader worker does per step (so data.num_workers ≥ data time / step time keeps up);
2. the training step (current loss + surface loss, double backward, Adam), also with
   ``model.net.matmul_precision=medium`` (bf16 / TF32 internals in the decoder pass's products), and with the
   winding cap (``model.winding_weight``) at the hinge's reach and at twice it (``model.winding_reach=2``: one more
   pass of f over the surface samples), and with f in a window of two jumps (``model.net.f_turns=2``, one tanh);
3. the decoder's first layer as implemented (code part once per shape) against the plain concatenation
   [code | RFF(x)] per point: time and peak memory of forward + double backward (CUDA: allocator peak;
   CPU: the size of the concatenated input the split avoids).

Medians of ``--repeats``. Prints a table and saves JSON under benchmarks/results/.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import time
from pathlib import Path

import torch

from deepcurrents.data.family import FamilyDataModule
from deepcurrents.losses import current_loss
from deepcurrents.models.autodecoder import AutodecoderModule
from deepcurrents.nn.current import spatial_gradient

PAPER = dict(rff=dict(num_frequencies=1024), net=dict(width=256, depth=4), latent=256)
CPU = dict(rff=dict(num_frequencies=256), net=dict(width=128, depth=3), latent=64)


def sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize()


def timed(fn, device, repeats: int) -> float:
    fn()
    sync(device)
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        sync(device)
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def first_layer_step(family, x, code, concatenate: bool) -> None:
    """ω's ∇f part and its backward (double backward), with the decoder's input either split (as
    implemented: the code's share of the first layer once per shape) or concatenated per point."""
    sin, cos = family.encoding.sin_cos(x)
    feats = torch.cat([sin, cos], -1).requires_grad_(True)
    if concatenate:
        f = family.mlp(torch.cat([code[:, None].expand(-1, x.shape[1], -1), feats], -1)).squeeze(-1)
    else:
        f = family.decode(feats, code)
    grad = family.encoding.input_gradient(spatial_gradient(f, feats, create_graph=True), sin, cos)
    current_loss(grad.flatten(0, 1)).backward()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default="data/anny/hands")
    parser.add_argument("--meshes", type=int, default=8)
    parser.add_argument("--samples", type=int, default=4000)
    size = parser.add_mutually_exclusive_group()
    size.add_argument("--paper", action="store_true", help="the paper's network (default on CUDA)")
    size.add_argument("--cpu", action="store_true", help="preset=cpu's network (default on CPU)")
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's)")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    device = torch.device(args.device)
    sizes = PAPER if args.paper or (not args.cpu and device.type == "cuda") else CPU

    dm = FamilyDataModule(args.data, max_meshes=args.meshes, meshes_per_batch=args.meshes,
                          num_samples=args.samples, num_surface_samples=args.samples)
    net = dict(activation="softplus", alpha_scale=1e-3, **sizes["net"])
    rff = dict(sigma=2.0, enabled=True, seed=0, **sizes["rff"])
    module = AutodecoderModule(net=net, rff=rff, optim=dict(lr=4e-4, step_size=60000, gamma=0.5),
                               latent_dim=sizes["latent"], boundary_dim=sizes["latent"],
                               **dm.model_kwargs()).to(device)
    stream = iter(dm.train_dataloader())
    data_s = timed(lambda: next(stream), torch.device("cpu"), args.repeats)

    batch = {k: v.to(device) for k, v in next(stream).items()}
    opt = torch.optim.Adam(module.parameters(), lr=4e-4)

    def step():
        opt.zero_grad()
        module.compute_losses(batch)["loss"].backward()
        opt.step()

    step_s = timed(step, device, args.repeats)
    module.family.matmul_precision = "medium"  # bf16 / TF32 internals in the decoder pass (nn.field_gradient)
    medium_s = timed(step, device, args.repeats)
    module.family.matmul_precision = "highest"

    def variant(weight: float = 0.0, reach: float = 1.0, f_turns: float = 0.0):
        def run():
            module.hparams.winding_weight, module.hparams.winding_reach = weight, reach
            module.family.f_turns = f_turns
            step()
        return run

    # the cap reuses the hinge's values at reach 1 and takes one more f pass over the surface samples at reach 2;
    # the window is a tanh of f and its gradient; interleaved with the plain step, one of each per round, so that
    # all see the same machine state
    variants = {"plain": variant(), "reach1": variant(5.0), "reach2": variant(5.0, 2.0), "window": variant(f_turns=2.0)}
    rounds = {name: [] for name in variants}
    for run in variants.values():
        run()
    sync(device)
    for _ in range(args.repeats):
        for name, run in variants.items():
            t = time.perf_counter()
            run()
            sync(device)
            rounds[name].append(time.perf_counter() - t)
    variant()()  # the plain module again for the first-layer timings
    plain_s = statistics.median(rounds["plain"])
    winding_s = {1.0: statistics.median(rounds["reach1"]) / plain_s, 2.0: statistics.median(rounds["reach2"]) / plain_s}
    window_ratio = statistics.median(rounds["window"]) / plain_s

    fam = module.family
    code = fam.code(fam.latents(batch["index"]), batch["loops"], batch["loop_mask"]).detach().requires_grad_(True)
    x = batch["x"]
    results = {}
    for name, concat in (("split", False), ("concatenated", True)):
        def fn(concat=concat):
            first_layer_step(fam, x, code, concat)

        if device.type == "cuda":
            torch.cuda.reset_peak_memory_stats()
        seconds = timed(fn, device, args.repeats)
        peak = torch.cuda.max_memory_allocated() if device.type == "cuda" else None
        results[name] = {"seconds": seconds, "peak_bytes": peak}
        fam.zero_grad(set_to_none=True)
        code.grad = None
    concat_input = x.shape[0] * x.shape[1] * (fam.code_dim + fam.encoding.out_dim) * 4

    report = {
        "device": str(device), "machine": platform.node(), "cpu_threads": torch.get_num_threads(),
        "meshes": args.meshes, "samples_per_mesh": args.samples, "network": sizes,
        "data_seconds_per_batch": data_s, "train_step_seconds": step_s, "train_step_seconds_medium": medium_s,
        "train_step_ratio_winding": winding_s[1.0], "train_step_ratio_winding_reach2": winding_s[2.0],
        "train_step_ratio_window": window_ratio,
        "workers_to_keep_up": data_s / step_s,
        "first_layer": results,
        "first_layer_time_ratio_concat_over_split": results["concatenated"]["seconds"] / results["split"]["seconds"],
        "concatenated_input_bytes": concat_input,
    }
    print(f"{device}, {args.meshes} meshes × {args.samples} points, network {sizes}")
    print(f"  data (augment + sample) per batch   {data_s:8.3f} s   (one worker)")
    print(f"  training step                       {step_s:8.3f} s   → workers needed ≈ {data_s / step_s:.1f}")
    print(f"  … with model.net.matmul_precision=medium {medium_s:8.3f} s   ({step_s / medium_s:.2f}× faster)")
    for reach, ratio in winding_s.items():
        print(f"  … with model.winding_weight=5 model.winding_reach={reach:g}: {ratio:.2f}× the step (interleaved)")
    print(f"  … with model.net.f_turns=2 (the window on f): {window_ratio:.2f}× the step (interleaved)")
    for name, r in results.items():
        mem = f"  peak {r['peak_bytes'] / 2**20:8.1f} MiB" if r["peak_bytes"] else ""
        print(f"  first layer {name:13s} ∇f + backward {r['seconds']:7.3f} s{mem}")
    print(f"  concatenated / split time: {report['first_layer_time_ratio_concat_over_split']:.2f}; the split "
          f"avoids a {concat_input / 2**20:.0f} MiB concatenated input")
    out = Path(__file__).parent / "results"
    out.mkdir(exist_ok=True)
    (out / f"family_step_{device.type}.json").write_text(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
