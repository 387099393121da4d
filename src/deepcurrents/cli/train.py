"""``python train.py experiment=NAME [overrides]`` (also ``deepcurrents-train``): trains and evaluates one
run (or a suite of runs) into Hydra's run directory; user errors end in one sentence and a non-zero exit."""

from __future__ import annotations

import shutil
import sys
from contextlib import contextmanager
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, ListConfig, OmegaConf

from deepcurrents.cli.common import exit_on_user_error
from deepcurrents.errors import ConfigError, NonFiniteLossError, UserInputError
from deepcurrents.experiments.config import CONFIG_DIR
from deepcurrents.experiments.multirun import FAILED_JOB_FILE, in_multirun
from deepcurrents.experiments.run_dir import writable_problem
from deepcurrents.experiments.runner import train


def run_cli(cfg: DictConfig) -> float | None:
    """Runs :func:`train`, turning user errors into one sentence and a non-zero exit (no traceback). In a
    multirun a job's user error (or NaN loss) ends that job, not the sweep (:func:`failed_job`).

    Returns the value an Optuna sweep minimises (``cfg.objective``), if set.
    """
    if in_multirun():
        exit_on_user_error(check_local_ddp_sweep, cfg)
        # a requeued job or a sweep run again into the same folder: an earlier attempt's failure is not this one's
        (Path(HydraConfig.get().runtime.output_dir) / FAILED_JOB_FILE).unlink(missing_ok=True)
        try:
            metrics = train(cfg)
        except (UserInputError, NonFiniteLossError) as err:
            return failed_job(err, cfg)
    else:
        metrics = exit_on_user_error(train, cfg)
    objective = cfg.get("objective")
    if metrics is not None and objective:
        return exit_on_user_error(objective_value, metrics, str(objective))
    return None


def check_local_ddp_sweep(cfg: DictConfig) -> None:
    """ConfigError for a multi-process DDP trainer inside a multirun on Hydra's local launcher: Lightning starts each
    further process with this command line, ``-m`` included, so every process walked the whole sweep beside the
    first (a second sweep folder, tables written twice, a job's failure deciding another process's exit)."""
    launcher = str(OmegaConf.select(HydraConfig.get(), "launcher._target_", default=""))
    trainer = cfg.get("trainer") or {}
    devices, nodes = trainer.get("devices", 1), trainer.get("num_nodes", 1)
    strategy = str(trainer.get("strategy") or "auto")
    # more than one process, started by re-running the script: Lightning's "auto" picks DDP for several devices;
    # ddp_spawn / ddp_fork start theirs from this process instead
    rerun = strategy == "auto" or ("ddp" in strategy and not any(w in strategy for w in ("spawn", "fork")))
    if launcher.endswith("BasicLauncher") and rerun and (devices, nodes) != (1, 1):
        raise ConfigError(f"trainer.devices={devices} with trainer.num_nodes={nodes} (strategy {strategy}: DDP) cannot "
                          "run inside a local multirun (-m): Lightning starts each further process with this command "
                          "line, so each would run the whole sweep; run its jobs one command at a time, or with "
                          "hydra/launcher=submitit_slurm on a cluster.")


def failed_job(err: Exception, cfg: DictConfig) -> float | None:
    """A sweep job that stopped on a user error or a NaN loss (a learning rate too high among those swept): its
    sentence goes to stderr and to the job folder's ``error.txt``, which the sweep's table lists
    (experiments.multirun, which also ends a grid sweep with status 2); the other jobs run. An Optuna trial scores
    the worst value there is for its direction."""
    job = HydraConfig.get()
    text = " ".join(str(err).split())
    print(f"error: job {job.job.num} ({' '.join(job.overrides.task)}): {text}", file=sys.stderr)
    job_dir = Path(job.runtime.output_dir)
    job_dir.mkdir(parents=True, exist_ok=True)
    (job_dir / FAILED_JOB_FILE).write_text(text + "\n")
    return worst_value() if cfg.get("objective") else None


def worst_value() -> float:
    """The worst value for the Optuna sweeper's direction: +inf when it minimises (its default), -inf when it
    maximises (``direction: maximize``, ``[maximize]`` or the sweeper's enum)."""
    direction = OmegaConf.select(HydraConfig.get().sweeper, "direction", default="minimize") \
        if HydraConfig.initialized() else "minimize"
    if isinstance(direction, (list, tuple, ListConfig)):
        direction = direction[0] if len(direction) == 1 else "minimize"
    return float("-inf") if "maximize" in str(direction).lower() else float("inf")


def objective_value(metrics: dict, objective: str) -> float:
    """The metric an Optuna sweep optimises; the worst value where the run wrote it empty (an empty mesh's ucd), one
    sentence where the run writes no such metric (a typo, or ucd of a minimal surface): a search over inf finds
    nothing."""
    if objective not in metrics:
        written = sorted(k for k, v in metrics.items() if isinstance(v, (int, float)) and not isinstance(v, bool))
        raise ConfigError(f"objective={objective!r} is not a metric this run writes; it writes "
                          f"{', '.join(written)}.")
    value = metrics[objective]
    return float(value) if value is not None else worst_value()


def command_line_dirs(argv: list[str]) -> dict[str, Path]:
    """The run and sweep directories the command line names (``hydra.run.dir=``, ``hydra.sweep.dir=``), by key;
    values that Hydra interpolates are left to Hydra."""
    dirs = {}
    for arg in argv:
        key, _, value = arg.lstrip("+").partition("=")
        if key in ("hydra.run.dir", "hydra.sweep.dir") and value and "${" not in value:
            dirs[key] = Path(value).expanduser()
    return dirs


def run_dir_problem(argv: list[str]) -> str | None:
    """One sentence if the command line's ``hydra.run.dir=`` or ``hydra.sweep.dir=`` names a file, a folder under a
    file, or a folder (or the nearest existing folder above it) that cannot be written: Hydra makes that folder and
    its log file before any of our code runs, and failed there with a FileExistsError or PermissionError traceback."""
    for key, path in command_line_dirs(argv).items():
        blocker = next((p for p in (path, *path.parents) if p.exists()), None)
        if blocker is not None and not blocker.is_dir():
            return (f"{key}={path} cannot be made: '{blocker}' is a file, not a folder; choose another run "
                    "directory.")
        problem = writable_problem(blocker) if blocker is not None else None
        if problem is not None:
            return (f"{key}={path} cannot be written: '{blocker}' does not take new files ({problem}); make it "
                    "writable or choose another run directory.")
    return None


def launcher_problem(argv: list[str]) -> str | None:
    """One sentence if the command line picks the SLURM launcher where SLURM's ``srun`` is not found (submitit's own
    check ends in a RuntimeError traceback after Hydra has set the sweep up)."""
    if "hydra/launcher=submitit_slurm" in argv and shutil.which("srun") is None:
        return ("hydra/launcher=submitit_slurm submits to SLURM, but `srun` is not found here; run it on the cluster's "
                "login node, or use hydra/launcher=submitit_local (or no launcher) on this machine.")
    return None


@contextmanager
def record_kept_on_refusal(run_dir: Path | None):
    """Hydra rewrites a run directory's record of the command (``.hydra/``) before any of our checks run; when the
    command is then refused in one sentence (status 2), the previous run's record is put back as it was."""
    record = run_dir / ".hydra" if run_dir is not None else None
    saved = {p.name: p.read_bytes() for p in record.iterdir() if p.is_file()} \
        if record is not None and record.is_dir() else None
    try:
        yield
    except SystemExit as stop:
        if stop.code == 2 and saved is not None:
            for p in record.iterdir():
                if p.is_file() and p.name not in saved:
                    p.unlink()
            for name, data in saved.items():
                (record / name).write_bytes(data)
        raise


@hydra.main(version_base="1.3", config_path=CONFIG_DIR, config_name="train")
def hydra_main(cfg: DictConfig) -> float | None:
    return run_cli(cfg)


def main() -> float | None:
    """The command (``python train.py …``, ``deepcurrents-train …``): Hydra's entry point, after the run directory
    given on the command line is checked (Hydra makes it first); a refused single run leaves that directory's
    previous record of its command (:func:`record_kept_on_refusal`)."""
    argv = sys.argv[1:]
    problem = run_dir_problem(argv) or launcher_problem(argv)
    if problem is not None:
        print(f"error: {problem}", file=sys.stderr)
        sys.exit(2)
    single = "-m" not in argv and "--multirun" not in argv  # a sweep's job folders are its own, new per sweep
    with record_kept_on_refusal(command_line_dirs(argv).get("hydra.run.dir") if single else None):
        return hydra_main()


if __name__ == "__main__":
    main()
