"""Reports of the reconstruction suites (``deepcurrents.experiments.tables``): the paper's Table 1 and the hand
ablation of Fig. 7. Each takes the suite directory and the members' results and writes md + csv + png."""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any

import matplotlib.pyplot as plt

from deepcurrents.experiments.tables import write_table

# Paper Table 1 (UCD, meshes in [-0.5, 0.5]^3, FAUST parts, 1e4 steps on an RTX 3090)
PAPER_TABLE1 = {
    "head": {"baseline": 0.0049, "ours": 0.0010},
    "hand": {"baseline": 0.0045, "ours": 0.0011},
    "torso": {"baseline": 0.0049, "ours": 0.00092},
    "foot": {"baseline": 0.0055, "ours": 0.00092},
}


def _fmt(v) -> str:
    return f"{v:.4g}" if isinstance(v, float) else ("" if v is None else str(v))


def _input_units(metrics: dict[str, Any], key: str):
    """A length metric in the target file's units: ``<key>_input_units`` where the run normalised its target
    (data.normalize), else ``<key>`` (already in those units), so that runs in different frames compare."""
    value = metrics.get(f"{key}_input_units")
    return value if value is not None else metrics.get(key)


def table1_rows(results: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One row per category from members named ``ours_<cat>`` and ``baseline_<cat>``; UCDs in the target
    file's units (``_input_units``)."""
    by_name = {r["name"]: r["metrics"] for r in results}
    cats = [r["name"].split("_", 1)[1] for r in results if r["name"].startswith("ours_")]
    rows = []
    for cat in cats:
        ours, base = by_name.get(f"ours_{cat}", {}), by_name.get(f"baseline_{cat}", {})
        paper = PAPER_TABLE1.get(cat, {})
        rows.append({
            "model": cat,
            "ucd_baseline": _input_units(base, "ucd"), "ucd_ours": _input_units(ours, "ucd"),
            "paper_ucd_baseline": paper.get("baseline"), "paper_ucd_ours": paper.get("ours"),
            "ucd_reverse_baseline": _input_units(base, "ucd_reverse"),
            "ucd_reverse_ours": _input_units(ours, "ucd_reverse"),
            "boundary_error_ours": ours.get("boundary_error"),
            "seconds_ours": ours.get("train_seconds"), "seconds_baseline": base.get("train_seconds"),
            "steps_ours": ours.get("steps"), "steps_baseline": base.get("steps"),
            "target": ours.get("target"),
        })
    return rows


def table1_report(out_dir: Path, results: list[dict[str, Any]], cfg=None) -> list[dict[str, Any]]:
    """Writes table1.csv (all columns), table1.md (the paper's layout with its numbers beside ours) and
    table1.png (UCD per category, ours vs baseline, ours vs paper)."""
    out_dir = Path(out_dir)
    rows = table1_rows(results)
    columns = list(rows[0]) if rows else ["model"]
    with open(out_dir / "table1.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=columns)
        writer.writeheader()
        writer.writerows(rows)
    lines = ["| Model | UCD (baseline) | UCD (ours) | paper: UCD (baseline) | paper: UCD (ours) | "
             "train s (ours / baseline) | steps (ours / baseline) |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        ours, base = r["ucd_ours"], r["ucd_baseline"]
        better = ours is not None and base is not None and ours < base
        ours_text = f"**{_fmt(ours)}**" if better else _fmt(ours)
        cells = [r["model"], _fmt(base), ours_text, _fmt(r["paper_ucd_baseline"]), _fmt(r["paper_ucd_ours"]),
                 f"{_fmt(r['seconds_ours'])} / {_fmt(r['seconds_baseline'])}",
                 f"{_fmt(r['steps_ours'])} / {_fmt(r['steps_baseline'])}"]
        lines.append("| " + " | ".join(cells) + " |")
    samples = int(cfg.evaluation.get("ucd_samples", 100_000)) if cfg is not None and "evaluation" in cfg else None
    short = [r["model"] for r in rows if r["seconds_ours"] and r["seconds_baseline"] is not None
             and r["seconds_baseline"] < 0.9 * r["seconds_ours"]]
    lines += ["", f"UCD: mean distance from {f'{samples:,}' if samples else 'the'} uniform samples of the target "
              "to the learned surface, in the units of the target's file (the dataset's [-0.5, 0.5]^3 box; "
              "ucd_input_units of a run that normalised its target). The baseline trains for the wall time of our "
              "run on the same category" + (f"; here it stopped short of it on {', '.join(short)} (see the "
                                            "seconds column)." if short else ".")]
    (out_dir / "table1.md").write_text("\n".join(lines) + "\n")

    fig, ax = plt.subplots(figsize=(6, 3.5), dpi=120)
    x = range(len(rows))
    series = [("ucd_baseline", "baseline (this run)", -0.3), ("ucd_ours", "DeepCurrents (this run)", -0.1),
              ("paper_ucd_baseline", "baseline (paper)", 0.1),
              ("paper_ucd_ours", "DeepCurrents (paper)", 0.3)]
    for key, label, dx in series:
        heights = [r[key] if r[key] is not None else 0.0 for r in rows]
        ax.bar([i + dx for i in x], heights, width=0.2, label=label)
    ax.set_xticks(list(x), [r["model"] for r in rows])
    ax.set_yscale("log")
    ax.set_ylabel("UCD")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out_dir / "table1.png", bbox_inches="tight")
    plt.close(fig)
    return rows


def ablation_report(out_dir: Path, results: list[dict[str, Any]], cfg=None) -> list[dict[str, Any]]:
    """hand_ablation.md / .csv (UCD and reverse UCD in the target file's units, as Table 1 — the run's own frame
    beside them when it normalised its target —, boundary error, mesh area, time per variant) and
    hand_ablation.png: the variants' mesh pictures side by side, as in Fig. 7."""
    out_dir = Path(out_dir)
    results = [{**r, "metrics": {**r["metrics"], "ucd_file": _input_units(r["metrics"], "ucd"),
                                 "ucd_reverse_file": _input_units(r["metrics"], "ucd_reverse")}} for r in results]
    columns = ["run", "ucd_file", "ucd_reverse_file", "ucd", "ucd_reverse", "chamfer", "boundary_error", "mesh_area",
               "target_area", "mesh_faces", "steps", "train_seconds"]
    rows = write_table(out_dir, results, cfg, columns=columns, name="hand_ablation")
    images = [(r["name"], Path(r["dir"]) / "mesh.png") for r in results]
    fig, axes = plt.subplots(1, len(images), figsize=(3 * len(images), 3.3), dpi=120, squeeze=False)
    for ax, (name, path), row in zip(axes[0], images, rows, strict=True):
        if path.is_file():
            ax.imshow(plt.imread(path))
        ax.set_axis_off()
        # an empty mesh has no UCD: say so (e.g. a surface that collapsed onto the minimal one inside the tube)
        ucd = f"UCD {_fmt(row['ucd_file'])}" if row.get("ucd_file") is not None else "no surface extracted"
        ax.set_title(f"{name}\n{ucd}", fontsize=9)
    fig.tight_layout()
    fig.savefig(out_dir / "hand_ablation.png", bbox_inches="tight")
    plt.close(fig)
    return rows
