"""Tables of results: one row per run with its metrics, as CSV and Markdown (suites and multiruns)."""

from __future__ import annotations

import csv
from pathlib import Path
from typing import Any

from omegaconf import DictConfig


def write_table(out_dir: Path, results: list[dict[str, Any]], cfg: DictConfig | None = None,
                columns: list[str] | None = None, name: str = "table") -> list[dict[str, Any]]:
    """Writes ``<name>.csv`` and ``<name>.md``: one row per member with its metrics. → the rows."""
    rows = [{"run": r["name"], **r["metrics"]} for r in results]
    if columns is None:
        columns = ["run"] + sorted({k for row in rows for k in row if k != "run"})
    with open(out_dir / f"{name}.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=columns, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)

    def fmt(v, column):  # polished areas carry their digits (eval.meshing.polish), the rest four
        digits = 7 if column.startswith(("mesh_area_polished", "mesh_area_extrapolated", "mesh_area_smooth")) else 4
        return f"{v:.{digits}g}" if isinstance(v, float) else ("" if v is None else str(v))

    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(fmt(row.get(c), c) for c in columns) + " |" for row in rows]
    (out_dir / f"{name}.md").write_text("\n".join(lines) + "\n")
    return rows
