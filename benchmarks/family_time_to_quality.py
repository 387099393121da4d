"""Time to quality for families: recipes of ``experiment=latent_hands`` side by side in one process, the mean UCD
over the training shapes against wall-clock seconds (issue 13's "fast family recipe").

    python benchmarks/family_time_to_quality.py --seconds 240 --recipes cpu \\
        --recipe "near=preset=cpu,data.sampling.kind=near" [--shapes 000 001 002 003] [--threads 1]

Each recipe trains the family (``--shapes`` of ``--data``) through the real code path (Hydra configs, the
DataModule and LightningModule of ``train.py``, Lightning with ``trainer.max_time``), one after another; the
callback of ``time_to_quality.py`` copies the decoder, encoders and codes at T/2^k (copying is the only work inside
the timed region). Afterwards, outside it, every copy is scored as the final evaluation scores a run: each training
shape meshed under its own code and unaugmented boundary (the recipe's meshing settings, or ``--resolution``), its
UCD (target → mesh, ``--ucd-samples``) and boundary error. The recipe order turns with ``--repeats`` so that a
change of load does not always hit the same recipe.

Writes ``benchmarks/results/<out>.csv`` (one row per copy and shape), ``<out>.png`` (mean UCD against seconds, log
axes, one line per recipe) and ``<out>.json`` (the final copies and the seconds each recipe needs to reach each
``--threshold``, as ratios to the first recipe).
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import platform
import sys
import tempfile
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from time_to_quality import ROOT, output_stem, resolve_recipes, time_to_reach, train_recipe, with_suffix  # noqa: E402  (a sibling script, not a package)

RECIPES: dict[str, list[str]] = {
    "paper": ["preset=paper"],  # the paper's sizes (8 meshes × 4000 samples, latent 256, 4 × 256 decoder)
    "cpu": ["preset=cpu"],
}


def score(module, copies: list[dict], ucd_samples: int, resolution: int | None, tmp: Path) -> list[dict]:
    """Every copy's training shapes meshed and measured as in ``AutodecoderModule.final_evaluation``."""
    if resolution:
        module.evaluation["mesh"] = {**dict(module.evaluation.get("mesh", {})), "resolution": int(resolution)}
    meshes = module.trainer.datamodule.meshes
    rows = []
    for rec in copies:
        module.family.load_state_dict(rec["state"])
        module.eval()
        base = {k: v for k, v in rec.items() if k != "state"}
        for i, shape in enumerate(meshes):
            loops = module.shape_loops(i)
            row, _ = module.evaluate_member(module.latent(i), loops, module.meshing_bounds([i]), shape.trimesh(),
                                            tmp / f"{i:03d}.ply", ucd_samples, seed=0)
            rows.append({**base, "shape": shape.name, "ucd": row["ucd"], "boundary_error": row["boundary_error"]})
    return rows


def write_csv(rows: list[dict], path: Path) -> None:
    fields = ["recipe", "repeat", "steps", "seconds", "train_seconds", "cpu_seconds", "shape", "ucd",
              "boundary_error", "load_before", "load_after"]
    with open(path, "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=fields, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)


def mean_ucd(rows: list[dict]) -> float:
    """Mean UCD over the shapes of one copy; an empty mesh (UCD None) counts as infinitely far."""
    values = [r["ucd"] if r["ucd"] is not None else float("inf") for r in rows]
    return float(np.mean(values))


def summarise(rows: list[dict]) -> list[dict]:
    """One record per recipe, repeat and copy: mean and worst UCD, mean boundary error."""
    out = []
    keys = dict.fromkeys((r["recipe"], r["repeat"], r["steps"]) for r in rows)
    for recipe, repeat, steps in keys:
        group = [r for r in rows if (r["recipe"], r["repeat"], r["steps"]) == (recipe, repeat, steps)]
        first = group[0]
        out.append({"recipe": recipe, "repeat": repeat, "steps": steps, "seconds": first["seconds"],
                    "train_seconds": first["train_seconds"], "cpu_seconds": first["cpu_seconds"],
                    "ucd_mean": mean_ucd(group),
                    "ucd_worst": max(r["ucd"] if r["ucd"] is not None else float("inf") for r in group),
                    # an empty mesh has no border (None): counted apart
                    "boundary_error_mean": float(np.mean([r["boundary_error"] for r in group
                                                          if r["boundary_error"] is not None] or [np.nan])),
                    "empty_meshes": sum(r["ucd"] is None for r in group),
                    "load_before": first["load_before"], "load_after": first["load_after"]})
    return out


def plot(records: list[dict], path: Path, threshold: float, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.0, 3.8))
    recipes = list(dict.fromkeys(r["recipe"] for r in records))
    for k, recipe in enumerate(recipes):
        for repeat in sorted({r["repeat"] for r in records if r["recipe"] == recipe}):
            pts = sorted((r["seconds"], r["ucd_mean"]) for r in records
                         if r["recipe"] == recipe and r["repeat"] == repeat and np.isfinite(r["ucd_mean"]))
            if pts:
                ax.plot(*zip(*pts, strict=True), marker="o", ms=3, color=f"C{k}",
                        label=recipe if repeat == 0 else None)
    ax.axhline(threshold, color="grey", lw=0.8, ls="--")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("seconds (wall clock, setup included)")
    ax.set_ylabel("mean UCD over the training shapes")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=240.0, help="training budget per recipe")
    ap.add_argument("--steps", type=int, default=None, help="a step budget instead")
    ap.add_argument("--data", default="data/anny/hands", help="the family's folder")
    ap.add_argument("--shapes", nargs="+", default=["000", "001", "002", "003"], help="file stems to train on")
    ap.add_argument("--recipes", nargs="+", default=["cpu"])
    ap.add_argument("--recipe", action="append", default=[], metavar="NAME=OVERRIDE,OVERRIDE",
                    help="an extra recipe as comma-separated Hydra overrides")
    ap.add_argument("--copies", type=int, default=5, help="weight copies per run, at T/2^k")
    ap.add_argument("--repeats", type=int, default=1, help="runs of each recipe (the order turns each time)")
    ap.add_argument("--resolution", type=int, default=None, help="marching cubes (default: the recipe's)")
    ap.add_argument("--ucd-samples", type=int, default=20000)
    ap.add_argument("--threshold", type=float, nargs="+", default=[0.03, 0.02, 0.015])
    ap.add_argument("--out", default="family_time_to_quality",
                    help="file stem: a name under benchmarks/results/, or a path with a folder")
    ap.add_argument("--threads", type=int, default=None,
                    help="torch threads (the loader worker takes a core too: 1 on a 2-core machine)")
    args = ap.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    recipes = resolve_recipes(RECIPES, args.recipe, args.recipes)
    folder = (ROOT / args.data) if not Path(args.data).is_absolute() else Path(args.data)
    files = [folder / f"{stem}.ply" for stem in args.shapes]
    missing = [str(f) for f in files if not f.is_file()]
    if missing:
        raise SystemExit(f"--shapes: no such mesh {missing[0]} (run `make data` first).")
    data = ["experiment=latent_hands", "data.path=[" + ",".join(str(f) for f in files) + "]", "data.held_out=0"]
    stem = output_stem(args.out)
    rows: list[dict] = []
    order = list(args.recipes)
    with tempfile.TemporaryDirectory() as tmp:
        for repeat in range(args.repeats):
            rotated = order[repeat % len(order):] + order[: repeat % len(order)]
            for recipe in rotated:
                load0 = os.getloadavg()[0]
                module, _, copies = train_recipe([*data, *recipes[recipe]], args.seconds, args.copies, args.steps,
                                                 part="family")
                load1 = os.getloadavg()[0]
                scored = score(module, copies, args.ucd_samples, args.resolution, Path(tmp))
                for r in scored:
                    r.update(recipe=recipe, repeat=repeat, load_before=load0, load_after=load1)
                rows.extend(scored)
                last = summarise(scored)[-1]
                print(f"{recipe:10s} repeat {repeat}: {last['steps']:5d} steps in {last['seconds']:6.1f} s "
                      f"(cpu {last['cpu_seconds']:6.1f} s): mean UCD {last['ucd_mean']:.4f}, worst "
                      f"{last['ucd_worst']:.4f}, boundary error {last['boundary_error_mean']:.2g}, "
                      f"{last['empty_meshes']} empty [load {load0:.1f}→{load1:.1f}]", flush=True)
                write_csv(rows, with_suffix(stem, ".csv"))  # after every run: a later failure keeps these

    records = summarise(rows)
    title = f"{Path(args.data).name} {', '.join(args.shapes)} ({torch.get_num_threads()} thread(s))"
    plot(records, with_suffix(stem, ".png"), args.threshold[-1], title)
    summary: dict = {}
    for threshold in args.threshold:
        times = {rc: [time_to_reach([r for r in records if r["recipe"] == rc and r["repeat"] == k], threshold,
                                    "ucd_mean") for k in range(args.repeats)] for rc in args.recipes}
        base = next((t for ts in times.values() for t in ts if t is not None), None)
        cells = [f"{rc} " + "/".join(f"{t:.0f} s ({t / base:.2f}×)" if t is not None else "—" for t in ts)
                 for rc, ts in times.items()]
        print(f"seconds to a mean UCD ≤ {threshold}: " + ", ".join(cells))
        summary[str(threshold)] = times
    final = [r for r in records if r["steps"] == max(q["steps"] for q in records
                                                     if (q["recipe"], q["repeat"]) == (r["recipe"], r["repeat"]))]
    with_suffix(stem, ".json").write_text(json.dumps({
        "args": vars(args), "machine": platform.processor() or platform.machine(), "threads": torch.get_num_threads(),
        "time_to_threshold": summary, "final": final, "copies": records}, indent=2))
    print(f"wrote {with_suffix(stem, '.csv')}, .png, .json")


if __name__ == "__main__":
    main()
