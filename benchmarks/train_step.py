"""One training step of the paper network (4096 samples, trefoil): time, matmul FLOPs, and the achieved
fraction of this machine's own fp32 matrix-multiply rate, measured in the same run.

    python benchmarks/train_step.py [--samples 4096] [--repeats 10] [--device cpu|cuda] [--threads T]
                                    [--net paper|cpu] [--skip-memory] [--no-keep-freed-memory] [--cpu-time]
                                    [--compile default|reduce-overhead|max-autotune]

Four ways of computing ω = ∇f + α and the loss's gradient, timed interleaved so that all see the same machine
state: ``closed_form`` (the default of NeuralCurrent: nn/field_gradient.py, one pass with a hand-written
backward), ``medium`` (the same pass with ``model.net.matmul_precision=medium``: bf16 internals in its products on
a CPU with AMX / AVX512-BF16, TF32 on a GPU; compared both with the IEEE fp32 GEMM rate and with the GEMM rate
under the same internals), ``features`` (autograd through the MLP, the Fourier features' Jacobian in closed
form: the previous default) and ``autograd`` (plain double-backward autograd through sin/cos, the authors'
way). ``--net cpu`` times the network of ``preset=cpu`` (256 frequencies, 3×128) instead. ``--compile MODE`` adds
``compiled``: the default's loss ``current_loss(model(x)[1])`` through ``torch.compile(mode=MODE)`` (backward
and Adam as in the others; ``reduce-overhead`` replays CUDA graphs on a GPU), with its compile seconds. Like a
training run, the process first lets glibc reuse freed memory (experiments.runner.keep_freed_memory;
``--no-keep-freed-memory`` to measure without).

On a CPU it also profiles five default steps: ``products_share_of_step`` (the matrix products' share of the operator
time, the ceiling that sin, cos, the activations and the other elementwise passes leave the fraction) and
``products_fraction_of_gemm_rate`` (the fraction over that share: how fast the products themselves run). Also
measures the default step's peak memory (``step_peak_mb``, what it allocates beyond the model and optimiser) and
that of the 2^20-sample mass evaluation. Prints a table and saves JSON under
benchmarks/results/.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import statistics
import time
from pathlib import Path

import torch
from torch.utils.flop_counter import FlopCounterMode

from deepcurrents.eval.metrics import mass_estimate
from deepcurrents.experiments.runner import keep_freed_memory
from deepcurrents.geometry import trefoil
from deepcurrents.losses import current_loss
from deepcurrents.nn import neural_current
from deepcurrents.nn.field_gradient import matmul_precision_scope


def sync(device):
    if device.type == "cuda":
        torch.cuda.synchronize()


def matmul_rate(device, n=2048, repeats=10, clock=time.perf_counter, reduced=False) -> float:
    """Best-of fp32 GEMM rate (FLOP/s) for an n×n×n product, the machine's practical peak; ``reduced``: with
    the bf16 / TF32 internals of ``model.net.matmul_precision=medium`` (nn.field_gradient)."""
    a, b = torch.randn(n, n, device=device), torch.randn(n, n, device=device)
    with matmul_precision_scope(device.type, reduced):
        for _ in range(2):
            a @ b
        sync(device)
        best = float("inf")
        for _ in range(repeats):
            t = clock()
            a @ b
            sync(device)
            best = min(best, clock() - t)
    return 2 * n**3 / best


class _GlobalOnly:
    """Stands in for FlopCounterMode's module tracker, whose hooks break autograd.grad (torch 2.13)."""

    parents = {"Global"}

    def __enter__(self):
        return self

    def __exit__(self, *args):
        return False


def count_flops(fn) -> int:
    """Matmul-class FLOPs of one call of ``fn`` (torch.utils.flop_counter's registry)."""
    counter = FlopCounterMode(display=False)
    counter.mod_tracker = _GlobalOnly()
    with counter:
        fn()
    return counter.get_total_flops()


PRODUCT_OPS = ("aten::mm", "aten::addmm", "aten::bmm", "aten::baddbmm")  # the ops whose FLOPs count_flops counts


def products_share(fn, repeats: int = 5) -> float:
    """On a CPU: the matrix products' share of ``fn``'s operator time, from ``torch.profiler`` self times (a ratio
    within the profiled calls, so a slow spell of the machine cancels; the profiler's overhead lands mostly on the
    many small elementwise ops, so it is a slight underestimate). It is the ceiling that the other operations leave
    the step's fraction of the GEMM rate, and that fraction over it is how fast the products themselves run."""
    from torch.profiler import ProfilerActivity, profile

    with profile(activities=[ProfilerActivity.CPU]) as prof:
        for _ in range(repeats):
            fn()
    events = prof.key_averages()
    return (sum(e.self_cpu_time_total for e in events if e.key in PRODUCT_OPS)
            / sum(e.self_cpu_time_total for e in events))


def step_peak_mb(fn, device) -> float:
    """Peak of the memory ``fn`` allocates through torch's allocator above what was allocated before it, MiB: on a
    CUDA device from the caching allocator's counters, on a CPU from the profiler's allocation events (glibc's
    RSS would hide a short-lived array that reuses freed pages). Catches an array kept alive longer than needed."""
    if device.type == "cuda":
        torch.cuda.synchronize()
        base = torch.cuda.memory_allocated()
        torch.cuda.reset_peak_memory_stats()
        fn()
        torch.cuda.synchronize()
        return (torch.cuda.max_memory_allocated() - base) / 2**20
    from torch.profiler import ProfilerActivity, profile

    with profile(activities=[ProfilerActivity.CPU], profile_memory=True) as prof:
        fn()
    current = peak = 0
    for event in sorted(prof.profiler.kineto_results.events(), key=lambda e: e.start_ns()):
        if event.name() == "[memory]":
            current += event.nbytes()
            peak = max(peak, current)
    return peak / 2**20


def autograd_omega(model, x):
    """The reference: ∇f by double-backward autograd all the way through sin/cos (the authors' way)."""
    x = x.clone().requires_grad_(True)
    (grad,) = torch.autograd.grad(model.f(x).sum(), x, create_graph=True)
    return grad + model.alpha(x.detach())


NETS = {"paper": {}, "cpu": {"num_frequencies": 256, "width": 128, "depth": 3}}
VARIANTS = ("closed_form", "medium", "features", "autograd")


def make_step(model, opt, samples, device, variant="closed_form", compile_mode=None):
    """One training step of ``variant``; ``compiled``: the default's loss through torch.compile(mode=compile_mode)
    (its backward compiled by AOTAutograd, Adam eager)."""
    compiled = (torch.compile(lambda x: current_loss(model(x, create_graph=True)[1]), mode=compile_mode)
                if variant == "compiled" else None)

    def step():
        x = torch.rand(samples, 3, device=device) * 2 - 1
        if variant == "autograd":
            loss = current_loss(autograd_omega(model, x))
        else:  # set on every call: the variants share the model (and the compiled graph was traced with these)
            model.gradient = "autograd" if variant == "features" else "closed_form"
            model.matmul_precision = "medium" if variant == "medium" else "highest"
            loss = compiled(x) if compiled is not None else current_loss(model(x, create_graph=True)[1])
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        return loss
    return step


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--samples", type=int, default=4096)
    ap.add_argument("--repeats", type=int, default=10)
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    ap.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's own choice)")
    ap.add_argument("--net", choices=sorted(NETS), default="paper")
    ap.add_argument("--skip-memory", action="store_true")
    ap.add_argument("--no-keep-freed-memory", action="store_true")
    ap.add_argument("--compile", default=None, choices=["default", "reduce-overhead", "max-autotune"],
                    help="also time the default step with its loss through torch.compile(mode=...)")
    ap.add_argument("--cpu-time", action="store_true",
                    help="time steps and GEMMs in this process's CPU seconds (with --threads 1: less sensitive to "
                         "other jobs on a shared machine than wall-clock seconds)")
    args = ap.parse_args()
    clock = time.process_time if args.cpu_time else time.perf_counter
    if args.threads:
        torch.set_num_threads(args.threads)
    kept = False if args.no_keep_freed_memory else keep_freed_memory()
    device = torch.device(args.device)
    torch.manual_seed(0)
    model = neural_current(3, loops=[torch.tensor(l, dtype=torch.float32) for l in trefoil()],
                          **NETS[args.net]).to(device)
    opt = torch.optim.Adam(model.parameters(), lr=5e-4)
    steps = {v: make_step(model, opt, args.samples, device, v) for v in VARIANTS}

    flops = {v: count_flops(step) for v, step in steps.items()}
    for step in steps.values():
        step()
    compile_seconds = None
    if args.compile:  # the same FLOPs as the default (the counter cannot see into a compiled graph)
        steps["compiled"] = make_step(model, opt, args.samples, device, "compiled", args.compile)
        flops["compiled"] = flops["closed_form"]
        sync(device)
        t = time.perf_counter()
        steps["compiled"]()
        sync(device)
        compile_seconds = time.perf_counter() - t
        for _ in range(3):  # CUDA graphs record on the first calls after compiling
            steps["compiled"]()
    # interleave the variants and GEMM-rate timings so that all see the same machine state
    times: dict[str, list[float]] = {v: [] for v in steps}
    rates, reduced_rates = [], []
    load_before = os.getloadavg()[0]
    for _ in range(args.repeats):
        rates.append(matmul_rate(device, repeats=3, clock=clock))
        reduced_rates.append(matmul_rate(device, repeats=3, clock=clock, reduced=True))
        for name, step in steps.items():
            sync(device)
            t = clock()
            step()
            sync(device)
            times[name].append(clock() - t)
    rate = statistics.median(rates)
    median = {v: statistics.median(times[v]) for v in steps}
    result = {
        "device": str(device), "machine": platform.processor() or platform.machine(),
        "threads": torch.get_num_threads(), "samples": args.samples, "net": args.net,
        "clock": "cpu" if args.cpu_time else "wall",
        "keep_freed_memory": kept, "load_average_before": load_before, "load_average_after": os.getloadavg()[0],
        "step_ms_median": 1e3 * median["closed_form"], "step_ms_min": 1e3 * min(times["closed_form"]),
        "step_gflop": flops["closed_form"] / 1e9,
        "achieved_gflops": flops["closed_form"] / median["closed_form"] / 1e9,
        "gemm_rate_gflops_median": rate / 1e9, "gemm_rate_gflops_best": max(rates) / 1e9,
        "fraction_of_gemm_rate": flops["closed_form"] / median["closed_form"] / rate,
    }
    if device.type == "cpu":  # where the rest of the step goes: the products' own rate, and their share as a ceiling
        share = products_share(steps["closed_form"])
        result.update({"products_share_of_step": share,
                       "products_fraction_of_gemm_rate": result["fraction_of_gemm_rate"] / share})
    result["step_peak_mb"] = step_peak_mb(steps["closed_form"], device)  # the default step's own arrays
    reduced_rate = statistics.median(reduced_rates)
    result.update({"reduced_gemm_rate_gflops_median": reduced_rate / 1e9,
                   "medium_fraction_of_reduced_gemm_rate": flops["medium"] / median["medium"] / reduced_rate})
    for v in VARIANTS[1:]:
        # medium is a faster variant of the default, the others slower ones: each ratio is the faster one's speed-up
        speedup = ({"medium_speedup": median["closed_form"] / median[v]} if v == "medium"
                   else {f"speedup_vs_{v}": median[v] / median["closed_form"]})
        result.update({f"{v}_step_ms_median": 1e3 * median[v], f"{v}_step_gflop": flops[v] / 1e9, **speedup,
                       f"{v}_fraction_of_gemm_rate": flops[v] / median[v] / rate})
    if args.compile:
        result.update({"compile_mode": args.compile, "compile_seconds": compile_seconds,
                       "compiled_step_ms_median": 1e3 * median["compiled"],
                       "compiled_speedup": median["closed_form"] / median["compiled"],
                       "compiled_fraction_of_gemm_rate": flops["compiled"] / median["compiled"] / rate})
    model.gradient, model.matmul_precision = "closed_form", "highest"
    if not args.skip_memory:
        if device.type == "cuda":
            torch.cuda.reset_peak_memory_stats()
        before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        t = time.perf_counter()
        mass_estimate(model, 1 << 20)
        result["mass_eval_seconds"] = time.perf_counter() - t
        if device.type == "cuda":
            result["mass_eval_peak_mb"] = torch.cuda.max_memory_allocated() / 2**20
        else:  # growth of the process's peak RSS during the evaluation (an upper bound of its own use)
            result["mass_eval_peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
            result["rss_before_mb"] = before / 1024
    for k, v in result.items():
        print(f"{k:>24}: {v:.4g}" if isinstance(v, float) else f"{k:>24}: {v}")
    out = Path(__file__).parent / "results"
    out.mkdir(exist_ok=True)
    suffix = ("" if args.net == "paper" else f"_{args.net}") + (f"_compile-{args.compile}" if args.compile else "")
    (out / f"train_step_{device.type}{suffix}.json").write_text(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
