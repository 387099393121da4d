"""The final evaluation of a trained checkpoint against its training, as ``train.py`` runs it after training.

    OMP_NUM_THREADS=1 python benchmarks/final_evaluation_cost.py outputs/…/checkpoints/last.ckpt

Times ``final_evaluation`` (mass estimate, mesh, writing the mesh files, sharpened bound) and the media callback's
render of the checkpoint's module, and the seconds of one training step of the same run configuration measured in
the same process (before and after, averaged, so that a change of the machine's load hits both); prints one JSON
line with the ratios to ``trainer.max_steps`` steps (a time-budgeted run's: the steps it made). To compare two trees
on a shared machine, run it alternately from each (``git worktree add /tmp/old <commit>``, then
``PYTHONPATH=/tmp/old/src python benchmarks/final_evaluation_cost.py …``): the ratios, not the seconds, are
comparable. ``--mass-refine 1`` evaluates with the plain mass estimate (``evaluation.mass_refine``),
``--mass-rel-stderr`` with another stop (``evaluation.mass_rel_stderr``), ``--mass-refine-mesh 0|1`` without or
with the final mesh's cells refined (``evaluation.mass_refine_mesh``; ``recipe=sharp`` has it), ``--mass-tube-radius 0``
without the tube about Γ (``evaluation.mass_tube_radius``).
A 2D run (``experiment=minimal_2d``) reports ``mass_length`` and ``curve_length``, a reconstruction (its step timed
with its own losses) ``ucd`` too; the grid method's checkpoints are refused (no network to time).
``benchmarks/time_to_quality.py --eval-cost`` does the same for a current trained 200 steps.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import torch
from omegaconf import OmegaConf

import deepcurrents
from deepcurrents.cli.common import exit_on_user_error
from deepcurrents.experiments.runner import build
from deepcurrents.models.callbacks import MediaCallback
from deepcurrents.models.current_module import CurrentModule
from deepcurrents.models.loading import load_module, read_checkpoint

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_args import check_range  # noqa: E402  (a sibling module, not a package)

# the final evaluation's numbers reported beside the seconds, by the run's dimension
METRIC_KEYS = {3: ("mass_samples", "mass_evaluations", "mass_area", "mass_area_stderr", "mesh_area",
                   "mass_area_sharpened", "ucd"),
               2: ("mass_samples", "mass_evaluations", "mass_length", "mass_length_stderr", "curve_length")}


def step_seconds(cfg, steps: int = 30, warm: int = 5) -> float:
    """Seconds per training step of the run configuration ``cfg`` (its DataModule's batches, the module's
    loss, backward, an Adam step), the mean over ``steps`` after ``warm``."""
    datamodule, module = build(cfg)
    batches = iter(datamodule.train_dataloader())
    opt = torch.optim.Adam(module.parameters(), lr=1e-4)
    for i in range(warm + steps):
        if i == warm:
            start = time.perf_counter()
        loss = module.compute_losses(next(batches))["loss"]  # the module's own losses (a reconstruction's too)
        opt.zero_grad()
        loss.backward()
        opt.step()
    return (time.perf_counter() - start) / steps


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("ckpt")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--mass-refine", type=int, default=None,
                    help="evaluation.mass_refine for this evaluation (default: the run's; 1 = the plain estimate)")
    ap.add_argument("--mass-rel-stderr", type=float, default=None,
                    help="evaluation.mass_rel_stderr for this evaluation (default: the run's)")
    ap.add_argument("--mass-refine-mesh", type=int, choices=(0, 1), default=None,
                    help="evaluation.mass_refine_mesh for this evaluation (default: the run's)")
    ap.add_argument("--mass-tube-radius", type=float, default=None,
                    help="evaluation.mass_tube_radius for this evaluation (default: the run's; 0 = no tube)")
    args = ap.parse_args()
    check_range(ap, "--threads", args.threads, 1)
    check_range(ap, "--mass-refine", args.mass_refine, 1)  # as train.py checks evaluation.mass_refine
    check_range(ap, "--mass-rel-stderr", args.mass_rel_stderr, 0.0)
    check_range(ap, "--mass-tube-radius", args.mass_tube_radius, 0.0)
    torch.set_num_threads(args.threads)
    # a missing or unreadable checkpoint, a model without the network's final evaluation (the grid method's, a
    # family's) or a run whose curve file is gone: one sentence and status 2, as the apps show it
    exit_on_user_error(measure, args)


def measure(args: argparse.Namespace) -> None:
    """Loads the checkpoint, times its final evaluation, render and training step, and prints the JSON line."""
    module = load_module(args.ckpt, expected=CurrentModule)  # one sentence for another kind (the grid's, a family's)
    if args.mass_refine is not None:
        module.evaluation["mass_refine"] = args.mass_refine
    if args.mass_refine_mesh is not None:
        module.evaluation["mass_refine_mesh"] = bool(args.mass_refine_mesh)
    if args.mass_rel_stderr is not None:
        module.evaluation["mass_rel_stderr"] = args.mass_rel_stderr
    if args.mass_tube_radius is not None:
        module.evaluation["mass_tube_radius"] = args.mass_tube_radius
    cfg = OmegaConf.create(module.run_config)
    load = os.getloadavg()[0]
    before = step_seconds(cfg)
    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        metrics = module.final_evaluation(tmp)
        evaluation = time.perf_counter() - start
        media = cfg.callbacks.get("media") or {}
        render = MediaCallback(every_n_steps=0, final=True, **{k: media[k] for k in
                               ("size", "samples", "grid", "azimuth", "elevation") if k in media})
        start = time.perf_counter()
        render.render(module, os.path.join(tmp, "render.png"))
        rendering = time.perf_counter() - start
    step = 0.5 * (before + step_seconds(cfg))
    steps = int(cfg.trainer.max_steps)
    if steps < 0:  # a time-budgeted run (trainer.max_steps=-1): the steps it made
        steps = int(read_checkpoint(args.ckpt)["global_step"])
    train = step * steps
    print(json.dumps({
        "tree": deepcurrents.__file__.split("/src/")[0], "seconds_per_step": step, "steps": steps,
        "train_seconds": train,
        "evaluation_seconds": evaluation, "render_seconds": rendering,
        "evaluation_per_train": evaluation / train, "with_render_per_train": (evaluation + rendering) / train,
        **{k: metrics[k] for k in METRIC_KEYS[2 if OmegaConf.select(cfg, "data.dim") == 2 else 3] if k in metrics},
        "load": [load, os.getloadavg()[0]],
    }))


if __name__ == "__main__":
    main()
