"""Results of a Hydra multirun side by side: when every job has finished (locally, on SLURM, or as the
trials of an Optuna sweep), :class:`MultirunTable` writes ``table.md`` and ``table.csv`` into the sweep
directory — one row per job: the overrides that differ between jobs, then its ``metrics.json``.

Registered in ``conf/hydra/default.yaml`` (``hydra.callbacks.multirun_table``), so
``python train.py -m experiment=recon_hand model.rff.sigma=1,2,4`` ends with the comparison table.
"""

from __future__ import annotations

import json
import logging
import sys
from pathlib import Path
from typing import Any

from hydra.core.hydra_config import HydraConfig
from hydra.experimental.callback import Callback
from hydra.types import RunMode
from omegaconf import DictConfig, OmegaConf

log = logging.getLogger(__name__)


FAILED_JOB_FILE = "error.txt"  # the sentence a sweep job stopped on (cli.train.failed_job)


def in_multirun() -> bool:
    """Whether this process runs a job of a Hydra multirun (``-m``: a grid sweep or an Optuna search)."""
    return HydraConfig.initialized() and HydraConfig.get().mode == RunMode.MULTIRUN


def is_optuna_search(hydra_cfg: Any) -> bool:
    """Whether Hydra's config (``hydra``) sweeps with the Optuna sweeper (``hparams_search=…``)."""
    return "optuna" in str(OmegaConf.select(hydra_cfg, "sweeper._target_", default="")).lower()


def job_failed(job_dir: Path) -> bool:
    """Whether a job's last finished attempt failed: its error.txt is newer than its metrics.json, if it has one (a
    requeued job or a sweep run again into the same folder keeps the other attempt's file). An attempt killed before
    it wrote either leaves the earlier attempt's result standing (its error.txt was cleared when it started)."""
    error, metrics = job_dir / FAILED_JOB_FILE, job_dir / "metrics.json"
    return error.is_file() and (not metrics.is_file() or error.stat().st_mtime >= metrics.stat().st_mtime)


def failed_jobs(sweep_dir: str | Path) -> list[dict[str, Any]]:
    """Each job of a sweep whose last attempt stopped on a user error or a NaN loss: its number, overrides and
    sentence."""
    jobs = []
    for path in Path(sweep_dir).glob(f"*/{FAILED_JOB_FILE}"):
        if not job_failed(path.parent):
            continue
        jobs.append({"num": path.parent.name, "overrides": job_overrides(path.parent),
                     "error": path.read_text().strip()})
    return sorted(jobs, key=_job_order)


def job_overrides(job_dir: Path) -> list[str]:
    """The Hydra overrides a sweep job ran with (its .hydra/overrides.yaml; none if it has not got that far)."""
    path = job_dir / ".hydra" / "overrides.yaml"
    return [str(o) for o in OmegaConf.load(path)] if path.is_file() else []


def _job_order(job: dict[str, Any]) -> tuple:
    """Numeric job directories in numeric order, others after them."""
    return (not job["num"].isdigit(), int(job["num"]) if job["num"].isdigit() else 0, job["num"])


def collect_jobs(sweep_dir: str | Path) -> list[dict[str, Any]]:
    """Each job directory of a sweep that has ``metrics.json`` from its last attempt: its number, Hydra overrides
    and metrics, ordered by job number. Jobs without metrics (failed, or suites) are left out."""
    jobs = []
    for metrics_path in Path(sweep_dir).glob("*/metrics.json"):
        job_dir = metrics_path.parent
        if job_failed(job_dir):  # an earlier attempt's metrics, not this one's
            continue
        try:
            metrics = json.loads(metrics_path.read_text())
        except json.JSONDecodeError:
            log.warning("%s is not valid JSON; left out of the table.", metrics_path)
            continue
        jobs.append({"num": job_dir.name, "dir": str(job_dir), "overrides": job_overrides(job_dir),
                     "metrics": metrics})
    return sorted(jobs, key=_job_order)


def common_overrides(jobs: list[dict[str, Any]]) -> set[str]:
    """The overrides every one of ``jobs`` ran with (the rest tell them apart)."""
    return set.intersection(*(set(j["overrides"]) for j in jobs)) if jobs else set()


def write_multirun_table(sweep_dir: str | Path, objective: str | None = None,
                         failed: list[dict[str, Any]] | None = None) -> list[dict[str, Any]]:
    """Writes ``table.md``/``table.csv`` of a sweep's finished jobs (rows named by the overrides that tell them
    apart from every job of the sweep, ``failed`` ones included, so that a row keeps its swept value when it alone
    finished; the objective's column first when given). → the rows."""
    from deepcurrents.experiments.tables import write_table

    jobs = collect_jobs(sweep_dir)
    if not jobs:
        return []
    common = common_overrides([*jobs, *(failed or [])])
    results = []
    for j in jobs:
        distinct = [o for o in j["overrides"] if o not in common]
        name = f"{j['num']}: {' '.join(distinct)}" if distinct else j["num"]
        results.append({"name": name, "metrics": j["metrics"]})
    numeric = (int, float, type(None))
    keys = sorted({k for r in results for k, v in r["metrics"].items() if isinstance(v, numeric)})
    if objective in keys:
        keys.remove(objective)
        keys.insert(0, objective)
    return write_table(Path(sweep_dir), results, columns=["run", *keys])


class MultirunTable(Callback):
    """Hydra callback: the table of a multirun's results, written when the multirun ends. Jobs that stopped on a
    user error are listed under it, and a grid sweep then ends with one sentence and status 2 (an Optuna search with
    a warning: its failed trials scored the worst value, and the best parameters stand)."""

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        sweep_dir = Path(config.hydra.sweep.dir)
        failed = failed_jobs(sweep_dir)
        rows = write_multirun_table(sweep_dir, config.get("objective"), failed)
        # jobs that ran a suite (experiment=table1 …) write their own tables, not a metrics.json of the job
        suites = [p.parent.name for p in sweep_dir.glob("*/suite.json") if not job_failed(p.parent)]
        if failed:
            if not rows:  # the failed jobs are still listed where the table would be (a stale table.csv goes)
                (sweep_dir / "table.csv").unlink(missing_ok=True)
                ran = (f"Jobs {', '.join(sorted(suites, key=lambda n: (len(n), n)))} ran suites (their tables are in "
                       "their folders).\n") if suites else "No job of this sweep finished.\n"
                (sweep_dir / "table.md").write_text(ran)
            common = common_overrides([*collect_jobs(sweep_dir), *failed])
            with open(sweep_dir / "table.md", "a") as fh:
                fh.write("\nFailed jobs:\n\n")
                for j in failed:
                    told = [o for o in j["overrides"] if o not in common] or j["overrides"]
                    fh.write(f"- {j['num']}: {' '.join(told)}: {j['error']}\n")
        if rows:
            log.info("%d runs side by side: %s", len(rows), sweep_dir / "table.md")
        if failed:
            first = failed[0]
            where = f"; the other {len(rows)} are in {sweep_dir / 'table.md'}" if rows else ""
            text = (f"{len(failed)} of {len(failed) + len(rows) + len(suites)} sweep jobs failed (job {first['num']}: "
                    f"{first['error'].rstrip('.')}){where}.")
            search = is_optuna_search(config.hydra)
            if search and rows:  # failed trials scored the worst value; the best parameters stand
                log.warning(text)
                return
            print(f"error: {text}", file=sys.stderr)
            sys.exit(2)
