"""What Lightning's loop adds to a training step, measured in one run (alternating variants).

    python benchmarks/loop_overhead.py [--steps 500] [--repeats 3] [--threads 1] [--overrides k=v ...]

Trains ``experiment=minimal_trefoil preset=cpu`` (no logger, tiny final evaluation) through ``train.py``'s own code
for ``--steps`` steps, alternating:

- ``log_every_step``: the model's ``self.log`` calls on every step (before 2026-12-01; the loggers still only
  write every ``trainer.log_every_n_steps``);
- ``log_when_written``: the present code (``DeepCurrentsModule.logs_this_step``): ``self.log`` only on the steps
  Lightning writes;
- ``bare``: the same module, batches, loss and Adam in a plain loop without Lightning: what remains of the loop's
  cost is the difference to it.

Reports each variant's wall-clock seconds per step (the runs' training clock; medians over the alternations, so
compare them as ratios, and only on a machine nobody else loads) and saves JSON under benchmarks/results/.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]


def compose(overrides: list[str]):
    from hydra import compose as hydra_compose
    from hydra import initialize_config_dir

    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base=None):
        return hydra_compose(config_name="train", overrides=overrides)


def run_lightning(overrides: list[str], steps: int, every_step: bool, out: Path) -> float:
    """Training seconds per step of ``train`` (the run's own training clock) for ``steps`` steps."""
    from deepcurrents.experiments.runner import train
    from deepcurrents.models.base import DeepCurrentsModule

    original = DeepCurrentsModule.logs_this_step
    if every_step:
        DeepCurrentsModule.logs_this_step = lambda self: True
    try:
        metrics = train(compose([*overrides, f"trainer.max_steps={steps}"]), out_dir=out)
    finally:
        DeepCurrentsModule.logs_this_step = original
    return metrics["train_seconds"] / steps


def run_bare(overrides: list[str], steps: int) -> float:
    """The same module, data and loss without Lightning (a plain loop with Adam): seconds per step."""
    from deepcurrents.experiments.runner import build
    from deepcurrents.losses import current_loss

    cfg = compose([*overrides, f"trainer.max_steps={steps}"])
    datamodule, module = build(cfg)
    datamodule.setup("fit")
    loader = iter(datamodule.train_dataloader())
    lr = float(cfg.model.optim.lr)
    opt = torch.optim.Adam(module.parameter_groups(lr), lr=lr)
    module.train()
    start = time.perf_counter()
    for _ in range(steps):
        batch = next(loader)
        _, omega = module.current(batch["x"], create_graph=True, alpha=batch.get("alpha"))
        loss = current_loss(omega, batch.get("metric"), batch.get("weight"))
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
    return (time.perf_counter() - start) / steps


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=500)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--overrides", nargs="*", default=[])
    ap.add_argument("--out", default="loop_overhead")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    overrides = ["experiment=minimal_trefoil", "preset=cpu", "logger=none", "trainer.enable_progress_bar=true",
                 "evaluation.mass_samples=1024", "evaluation.mesh.resolution=16", "callbacks.media.final=false",
                 "callbacks.model_checkpoint.every_n_train_steps=100000", *args.overrides]
    work = ROOT / "benchmarks" / "results" / "loop_overhead_runs"
    rows: dict[str, list[float]] = {"log_every_step": [], "log_when_written": [], "bare": []}
    for r in range(args.repeats):
        order = ["log_every_step", "log_when_written", "bare"]
        if r % 2:
            order.reverse()
        for name in order:
            if name == "bare":
                per_step = run_bare(overrides, args.steps)
            else:
                per_step = run_lightning(overrides, args.steps, name == "log_every_step", work / f"{name}_{r}")
            rows[name].append(per_step)
            print(f"repeat {r} {name:18s} {1e3 * per_step:7.2f} ms / step", flush=True)
    med = {k: statistics.median(v) for k, v in rows.items()}
    print("\nmedian ms / step: " + ", ".join(f"{k} {1e3 * v:.2f}" for k, v in med.items()))
    print(f"log_every_step / log_when_written: {med['log_every_step'] / med['log_when_written']:.3f}; "
          f"log_when_written / bare: {med['log_when_written'] / med['bare']:.3f}")
    result = {"steps": args.steps, "threads": args.threads, "overrides": overrides, "seconds_per_step": rows,
              "median": med, "machine": platform.processor() or platform.machine(),
              "load_average": list(os.getloadavg())}
    out = ROOT / "benchmarks" / "results" / f"{args.out}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=2))
    print(f"saved {out}")


if __name__ == "__main__":
    sys.exit(main())
