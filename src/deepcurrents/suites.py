"""Experiments made of several runs (Fig. 4, Table 1, the hand ablation): one command runs each member
in its own sub-directory, then a report function collects their metrics into a table and a figure.

An experiment declares a suite in its config::

    suite:
      runs:                                  # each: a name and Hydra overrides of the root config
        - {name: full, overrides: [experiment=recon_hand, ablation=full]}
        - {name: relu, overrides: [experiment=recon_hand, ablation=relu]}
      report: deepcurrents.suites.write_table  # callable(suite_dir, results, cfg) → writes files

The command line's own overrides (e.g. ``preset=cpu``, ``trainer=gpu``) are passed on to every member,
except ``experiment=`` (each member names its own). Members run in this process, one after another.
"""

from __future__ import annotations

import csv
import json
import logging
from pathlib import Path
from typing import Any

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

log = logging.getLogger(__name__)


def inherited_overrides() -> list[str]:
    """The command line's overrides that every suite member inherits (all but ``experiment=``)."""
    if not HydraConfig.initialized():
        return []
    return [o for o in HydraConfig.get().overrides.task if not o.lstrip("+~").startswith("experiment=")]


def run_suite(cfg: DictConfig, out_dir: Path, extra_overrides: list[str] | None = None) -> list[dict[str, Any]]:
    """Runs every member of ``cfg.suite`` into ``out_dir/<name>`` and calls the report. → member results."""
    from deepcurrents.train import train

    inherited = inherited_overrides() if extra_overrides is None else list(extra_overrides)
    results = []
    for member in cfg.suite.runs:
        name = str(member.name)
        overrides = list(member.overrides) + [o for o in inherited if not o.startswith("hydra.")]
        member_dir = out_dir / name
        log.info("suite member %s: %s", name, " ".join(overrides))
        member_cfg = hydra.compose(config_name="train", overrides=overrides + [f"paths.output_dir={member_dir}"])
        metrics = train(member_cfg, out_dir=member_dir)
        results.append({"name": name, "overrides": overrides, "dir": str(member_dir), "metrics": metrics or {}})
    (out_dir / "suite.json").write_text(json.dumps(results, indent=2))
    report = cfg.suite.get("report") or "deepcurrents.suites.write_table"
    hydra.utils.get_method(report)(out_dir, results, cfg)
    return results


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

    def fmt(v):
        return f"{v:.4g}" if isinstance(v, float) else ("" if v is None else str(v))

    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(fmt(row.get(c)) for c in columns) + " |" for row in rows]
    (out_dir / f"{name}.md").write_text("\n".join(lines) + "\n")
    return rows
