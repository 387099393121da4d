"""Running experiments: config → DataModule → LightningModule → Trainer → final evaluation, and suites
(experiments made of several runs, e.g. Fig. 4, Table 1, the hand ablation).

A suite is declared in an experiment's config::

    suite:
      runs:                                  # each: a name and Hydra overrides of the root config
        - {name: full, overrides: [experiment=recon_hand, ablation=full]}
        - {name: relu, overrides: [experiment=recon_hand, ablation=relu]}
      report: deepcurrents.experiments.tables.write_table  # callable(suite_dir, results, cfg) → writes files
      check: null                            # optional callable(cfg): the report's own inputs, checked first
      common: []                             # optional overrides every member takes before its own

The command line's own overrides (e.g. ``preset=cpu``, ``trainer=gpu``) are passed on to every member,
except ``experiment=`` (each member names its own) and ``suite.*`` (the suite's own settings). Members run in this
process, one after another, or with ``suite.jobs: N`` (or ``auto``: one per core on a CPU, one on a GPU, at most the
members) in N processes side by side, each member a ``python -m deepcurrents.cli.train`` of its own overrides.

The command ``python train.py …`` (``deepcurrents.cli.train``) is a thin wrapper around :func:`train`.
"""

from __future__ import annotations

import ctypes
import errno
import inspect
import json
import logging
import os
import re
import shlex
import sys
import time
from contextlib import contextmanager, nullcontext
from pathlib import Path
from typing import Any

import hydra
import lightning as L
import torch
from hydra.core.hydra_config import HydraConfig
from hydra.errors import ConfigCompositionException, InstantiationException
from lightning.pytorch.accelerators import CPUAccelerator
from lightning.pytorch.callbacks.progress import ProgressBar
from lightning.pytorch.utilities.exceptions import MisconfigurationException, SIGTERMException
from omegaconf import DictConfig, OmegaConf

from deepcurrents.errors import ConfigError, UserInputError, positive_int
from deepcurrents.eval.metrics import metrics_json
from deepcurrents.experiments.config import trainer_overrides, validate_config, warn_unread_schedule_settings
from deepcurrents.experiments.loggers import LogRunConfig, build_logger, finished_loggers
from deepcurrents.experiments.multirun import in_multirun, is_optuna_search
from deepcurrents.experiments.run_dir import (
    RunLock,
    check_free_space,
    is_global_rank_zero,
    make_run_dir,
    resume_path,
)
from deepcurrents.models.callbacks import progress_bar
from deepcurrents.models.checkpointing import AtomicCheckpointIO, PreemptionCheckpoint, ResumeState, kept_checkpoint
from deepcurrents.models.current_module import boundary_spec
from deepcurrents.models.loading import check_resumable, warm_start

log = logging.getLogger("deepcurrents")

# glibc's malloc returns every block of 32 MB or more to the system when it is freed, so each training step of the
# paper network (4096 samples × 2048 features = 32 MB per feature array) page-faulted its arrays back in. Blocks
# below this size are reused from the heap; the price is a higher peak where the heap keeps what it freed
# (docs/notes/speed.md).
MMAP_THRESHOLD = 256 << 20


def keep_freed_memory(threshold: int = MMAP_THRESHOLD) -> bool:
    """Lets glibc reuse freed blocks below ``threshold`` bytes instead of unmapping them (``mallopt``); the heap
    above twice that is still given back. Linux with glibc only; elsewhere nothing changes. → whether it applied."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL("libc.so.6")
    except OSError:  # another C library (musl)
        return False
    m_trim_threshold, m_mmap_threshold = -1, -3
    return bool(libc.mallopt(m_mmap_threshold, threshold)) and bool(libc.mallopt(m_trim_threshold, 2 * threshold))


def instantiate(node: DictConfig, **kwargs):
    """hydra.utils.instantiate, but a UserInputError raised inside a constructor comes out as itself
    (Hydra wraps it in an InstantiationException with the target's traceback text), and a key of the config that
    a constructor does not take (a misspelt one added with Hydra's ``+``) is one sentence naming it."""
    try:
        return hydra.utils.instantiate(node, **kwargs)
    except InstantiationException as err:
        cause = err.__cause__
        while cause is not None and not isinstance(cause, UserInputError):
            unknown = re.search(r"([\w.]+?)(?:\.__init__)?\(\) got an unexpected keyword argument '([^']+)'",
                                str(cause))
            if isinstance(cause, TypeError) and unknown is not None:
                message = unknown_key_message(node, *unknown.groups())
                if message is not None:  # else no key of the config has that name: a programming error
                    raise ConfigError(message) from None
            cause = cause.__cause__
        if cause is not None:
            raise cause from None
        raise


def unknown_key_message(node: DictConfig, owner: str, name: str) -> str | None:
    """One sentence for a key ``name`` under ``node`` that ``owner``'s constructor does not take, naming it where it
    can be told from its namesakes (the one added with ``+`` on the command line, else the one beside ``owner``'s own
    ``_target_``), never a valid one; None when no key under ``node`` has that name (the argument did not come from
    the config)."""
    prefix = node._get_full_key(None) or ""
    paths: list[str] = []

    def walk(value, path: str) -> None:
        if path.rsplit(".", 1)[-1] == name:
            paths.append(path)
        if isinstance(value, dict):
            for key, child in value.items():
                walk(child, f"{path}.{key}" if path else str(key))

    walk(OmegaConf.to_container(node, resolve=False), prefix)
    if not paths:
        return None
    if len(paths) > 1 and HydraConfig.initialized():  # the keys the command line added: the culprit among namesakes
        added = {o.lstrip("+").split("=", 1)[0] for o in HydraConfig.get().overrides.task if o.startswith("+")}
        paths = [p for p in paths if p in added] or paths
    if len(paths) > 1:  # the one beside the owner's own _target_, if that tells them apart
        def target_beside(path: str) -> str:
            parent = path[len(prefix):].lstrip(".").rpartition(".")[0]
            return str(OmegaConf.select(node, f"{parent}._target_" if parent else "_target_", default="") or "")

        beside = [p for p in paths if target_beside(p).endswith(owner)]
        paths = beside if len(beside) == 1 else paths
    tail = "a misspelt key, or one added with '+' that nothing reads); `--cfg job` prints the settings there are."
    if len(paths) == 1:
        return f"{paths[0]} is not a setting {owner} takes ({tail}"
    return f"A key named '{name}' is not a setting {owner} takes ({tail}"


def output_dir(cfg: DictConfig) -> Path:
    """The run directory: Hydra's when running under Hydra, else ``cfg.paths.output_dir``."""
    if HydraConfig.initialized():
        return Path(HydraConfig.get().runtime.output_dir)
    return Path(cfg.paths.output_dir)


def build_callbacks(cfg: DictConfig, out_dir: Path) -> list:
    callbacks = []
    for name, cb in (cfg.get("callbacks") or {}).items():
        if cb is None:
            continue
        kwargs = {"dirpath": str(out_dir / "checkpoints")} if name == "model_checkpoint" else {}
        callbacks.append(instantiate(cb, **kwargs))
    if cfg.get("trainer", {}).get("enable_progress_bar", True) \
            and not any(isinstance(cb, ProgressBar) for cb in callbacks):
        bar = progress_bar()
        if bar is not None:
            callbacks.append(bar)
    return callbacks


def build_trainer(cfg: DictConfig, **kwargs) -> L.Trainer:
    """The Lightning Trainer of ``cfg.trainer``; settings Lightning cannot honour here (``trainer=gpu`` without
    a GPU, ``devices=0``, an unknown precision, an accelerator whose package is missing) are one sentence."""
    try:
        return instantiate(cfg.trainer, **kwargs)
    except InstantiationException as err:
        cause = err.__cause__ if err.__cause__ is not None else err
        text = " ".join(str(cause).split()).rstrip(".") or type(cause).__name__
        chosen = ", ".join(f"trainer.{k}={cfg.trainer[k]}" for k in ("accelerator", "devices", "strategy", "precision")
                           if k in cfg.trainer)
        raise ConfigError(f"Lightning cannot build a trainer from {chosen} here: {text} (trainer=cpu runs "
                          "anywhere).") from None


def available_cores() -> int:
    """CPU cores this process may run on (its affinity mask where the platform has one)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # macOS, Windows
        return os.cpu_count() or 1


def training_threads(cfg: DictConfig, trainer: L.Trainer) -> int | None:
    """Torch threads of each training process (``torch_threads``): an integer as given; ``auto`` on a CPU run,
    the cores left to each process beside its loader workers, (cores // processes on this node) − data.num_workers,
    at least 1, when that is fewer than torch's own choice (which counts every core, so trainer and workers,
    or several DDP processes, fight over them); null or a GPU run: None, torch's choice."""
    value = cfg.get("torch_threads")
    if value is None:
        return None
    if value != "auto":
        threads, cores = positive_int("torch_threads", value), available_cores()
        if threads > cores and isinstance(trainer.accelerator, CPUAccelerator):
            log.warning("torch_threads=%d is more than the %d core(s) this process may use: the threads wait on each "
                        "other (999 on 2 cores made a 100-step run 55x slower); use at most %d, or auto.",
                        threads, cores, cores)
        return threads
    if not isinstance(trainer.accelerator, CPUAccelerator):
        return None
    workers = int(cfg.get("data", {}).get("num_workers", 0) or 0)
    threads = max(1, available_cores() // max(1, trainer.num_devices) - workers)
    return threads if threads < torch.get_num_threads() else None


def evaluation_threads(cfg: DictConfig) -> int | None:
    """Torch threads of the final evaluation: an integer ``torch_threads`` holds for the whole run (a user who
    shares the cores with other jobs asked for it); ``auto`` and null give torch's choice back, since the loader
    workers that ``auto`` left cores for are gone by then."""
    value = cfg.get("torch_threads")
    return None if value is None or value == "auto" else positive_int("torch_threads", value)


@contextmanager
def torch_threads(threads: int | None):
    """``torch.set_num_threads(threads)`` for the block (None: unchanged), then torch's previous setting: the
    final evaluation after training has the cores to itself again."""
    before = torch.get_num_threads()
    if threads is not None:
        torch.set_num_threads(threads)
    try:
        yield
    finally:
        torch.set_num_threads(before)


def build(cfg: DictConfig):
    """The DataModule and the LightningModule of a run, its settings checked first (``experiments.schema``: one
    sentence for an impossible one; the constructors trust them) and its inputs read; trains nothing."""
    validate_config(cfg)
    datamodule = instantiate(cfg.data, _convert_="all")
    spec = boundary_spec(datamodule.boundary) if hasattr(datamodule, "boundary") else None
    kwargs = {"boundary": spec} if spec is not None else {}
    extra = getattr(datamodule, "model_kwargs", None)
    if callable(extra):
        kwargs.update(extra())
    module = instantiate(cfg.model, _convert_="all", **kwargs)
    module.run_config = OmegaConf.to_container(cfg, resolve=True)
    return datamodule, module


def train(cfg: DictConfig, out_dir: Path | None = None, resume_hint: str | None = None,
          member: str | None = None, overrides: list[str] | None = None) -> dict[str, Any] | None:
    """Trains and evaluates one run into ``out_dir`` (default: the run directory); returns its metrics
    (None on non-zero DDP ranks). A config with a ``suite`` runs each member instead (:func:`run_suite`).

    Before training: the inputs are checked (one sentence on a bad one), the run directory must be writable
    with room for the checkpoints and must not be in use by another run (a lock file, experiments.run_dir),
    and a checkpoint to resume from (``ckpt_path=FILE|auto``) must be a DeepCurrents checkpoint of this model
    kind and problem (models.loading.check_resumable). SIGTERM or SIGUSR1 (preemption) or Ctrl-C writes
    ``checkpoints/last.ckpt`` after the running step and ends the process with status 143 (Ctrl-C: 130);
    ``ckpt_path=auto`` continues from it. ``member``, ``overrides``: the suite member this run is and its overrides
    (its logged run's name and record; else the command line's).
    """
    out_dir = make_run_dir(Path(out_dir) if out_dir is not None else output_dir(cfg))
    with RunLock(out_dir) if is_global_rank_zero() else nullcontext():
        if cfg.get("suite"):
            run_suite(cfg, out_dir)
            return None
        return _train_one(cfg, out_dir, resume_hint, member, overrides)


def _train_one(cfg: DictConfig, out_dir: Path, resume_hint: str | None = None, member: str | None = None,
               overrides: list[str] | None = None) -> dict[str, Any] | None:
    keep_freed_memory()
    L.seed_everything(positive_int("seed", cfg.seed, minimum=0), workers=True, verbose=False)
    datamodule, module = build(cfg)  # checks the settings first (experiments.schema)
    if is_global_rank_zero():
        warn_unread_schedule_settings(cfg, inherited_overrides())
    resume = resume_path(cfg.get("ckpt_path"), out_dir)
    resumed_step = _resumed_step(cfg, resume, module)
    if cfg.get("init_from") and resume is None:
        copied = warm_start(module, cfg.init_from)
        log.info("Warm start: %d network tensors from %s.", copied, cfg.init_from)
    check_free_space(out_dir, module)
    module.check_final_mesh()
    last = out_dir / "checkpoints" / "last.ckpt"
    preemption = PreemptionCheckpoint(last)
    trainer: L.Trainer = build_trainer(
        cfg,
        logger=build_logger(cfg, out_dir, member),
        callbacks=[*build_callbacks(cfg, out_dir), ResumeState(), preemption,
                   LogRunConfig({**module.run_config, "overrides": command_overrides() if overrides is None
                                 else overrides})],
        plugins=[AtomicCheckpointIO()],
        default_root_dir=str(out_dir),
        enable_autolog_hparams=False,  # LogRunConfig logs the whole config instead of the module's arguments
        **trainer_overrides(cfg),  # max_time in seconds → timedelta
    )
    with finished_loggers(trainer):  # one logged run per job: the next job of a sweep or suite starts its own
        _fit(cfg, trainer, module, datamodule, resume, preemption, out_dir, resume_hint)
        # the final state, whatever step it ended on (periodic checkpoints may be older)
        trainer.save_checkpoint(last, weights_only=False)
        if trainer.interrupted:
            log.warning("Training was interrupted; evaluating the model as it is.")
        elif resumed_step is not None and trainer.global_step == resumed_step and trainer.is_global_zero:
            log.warning("No step was trained: %s had already used the run's budget (its steps or seconds); the "
                        "final evaluation scores it as it is.", resume)
        if not trainer.is_global_zero:
            return None
        return _final_evaluation(cfg, trainer, module, out_dir)


def _resumed_step(cfg: DictConfig, resume: Path | None, module: L.LightningModule) -> int | None:
    """The step of the checkpoint a run resumes from (None: a fresh run), with a warning when the run's
    ``trainer.max_steps`` leaves nothing to train."""
    if resume is None:
        return None
    resumed_step = int(check_resumable(resume, module).get("global_step") or 0)
    max_steps = cfg.trainer.get("max_steps")
    if is_global_rank_zero() and isinstance(max_steps, int) and 0 <= max_steps <= resumed_step:
        log.warning("%s is at step %d, which trainer.max_steps=%d does not exceed: no step will be trained, and "
                    "the final evaluation scores the checkpoint as it is (raise trainer.max_steps to train on).",
                    resume, resumed_step, max_steps)
    return resumed_step


def _fit(cfg: DictConfig, trainer: L.Trainer, module: L.LightningModule, datamodule: L.LightningDataModule,
         resume: Path | None, preemption: PreemptionCheckpoint, out_dir: Path, resume_hint: str | None) -> None:
    """``trainer.fit``, with a trainer setting Lightning refuses, a full disk and a stop signal said in one
    sentence (the last checkpoint kept)."""
    threads = training_threads(cfg, trainer)
    if threads is not None:
        log.info("Training with %d torch thread(s) beside %s loader worker(s) (torch_threads).", threads,
                 cfg.data.get("num_workers", 0))
    try:  # weights_only: resuming never unpickles objects (AtomicCheckpointIO insists as well)
        with torch_threads(threads):
            trainer.fit(module, datamodule=datamodule, ckpt_path=resume, weights_only=True)
    except MisconfigurationException as err:  # a trainer setting Lightning checks only once fitting runs
        text = " ".join(str(err).split()).rstrip(".")
        raise ConfigError(f"Lightning refused the trainer settings: {text}.") from None
    except OSError as err:  # a logger's file (the CSV logger's metrics) on a disk that filled up during training
        if err.errno not in (errno.ENOSPC, errno.EDQUOT):
            raise
        where = f": {err.filename}" if err.filename else ""
        raise UserInputError(f"Writing the run's files failed at step {trainer.global_step} ({err.strerror}{where})"
                             f"; {kept_checkpoint(trainer)}; free some space. "
                             f"{resume_hint or continue_hint(out_dir)}") from None
    except SIGTERMException:
        name = preemption.signal_name
        if trainer.is_global_zero:
            hint = resume_hint or continue_hint(out_dir)
            log.warning("Stopped by %s at step %d; %s holds it. %s", "Ctrl-C" if name == "SIGINT" else name,
                        trainer.global_step, preemption.path, hint)
        raise SystemExit(130 if name == "SIGINT" else 143) from None


def _final_evaluation(cfg: DictConfig, trainer: L.Trainer, module: L.LightningModule,
                      out_dir: Path) -> dict[str, Any]:
    """The module's final evaluation (timed, written to metrics.json), the final media, and the final metrics sent
    to every logger (rank zero only)."""
    started = time.perf_counter()
    with torch_threads(evaluation_threads(cfg)):
        metrics = module.final_evaluation(out_dir)
    if metrics is not None:  # the final evaluation's own cost, beside train_seconds
        metrics["evaluation_seconds"] = round(time.perf_counter() - started, 3)
        module.write_metrics(out_dir, metrics)
    log.info("metrics: %s", json.dumps(metrics))
    if metrics is not None and (sentence := module.summary(metrics)):
        log.info("%s", sentence)
    for cb in trainer.callbacks:  # final media (deepcurrents.models.callbacks.MediaCallback) before loggers close
        hook = getattr(cb, "on_final_evaluation", None)
        if callable(hook):
            hook(trainer, module, metrics, out_dir)
    for lg in trainer.loggers:
        lg.log_metrics({f"final/{k}": v for k, v in metrics.items() if isinstance(v, (int, float))},
                       step=int(module.global_step))
        if hasattr(lg, "experiment") and hasattr(lg.experiment, "summary"):
            lg.experiment.summary.update({f"final/{k}": v for k, v in metrics.items()})
        lg.finalize("success")
    return metrics


def continue_hint(out_dir: Path) -> str:
    """How to continue a stopped run: a single run from its directory; a multirun's job by the same command again
    into the same sweep directory (``hydra.run.dir`` means nothing under ``-m``, and the jobs after it have not
    run); an Optuna trial not at all (a search samples new trials)."""
    if not in_multirun():
        return f"Continue with ckpt_path=auto hydra.run.dir={out_dir}."
    sweep = HydraConfig.get().sweep.dir
    if is_optuna_search(HydraConfig.get()):
        return ("An Optuna search does not resume its trials: run it again (hydra.sweeper.storage=sqlite:///….db "
                "keeps the study's finished trials).")
    return (f"Continue the sweep with the same command plus ckpt_path=auto hydra.sweep.dir={sweep} (each job from "
            "its own checkpoint; the jobs not yet run then run).")


def command_overrides() -> list[str]:
    """The command line's overrides (a multirun job's own values included); none outside Hydra."""
    return list(HydraConfig.get().overrides.task) if HydraConfig.initialized() else []


def inherited_overrides() -> list[str]:
    """The command line's overrides that every suite member inherits (all but ``experiment=`` and the suite's own
    ``suite.*``)."""
    return [o for o in command_overrides() if not o.lstrip("+~").startswith(("experiment=", "suite."))]


# The data settings that choose a run's problem (which curve, mesh, point cloud, family or part); the others modify
# it (data.curve_vertices, data.source, data.index, …) and may reach every member of a suite alike.
PROBLEM_CHOICE_KEYS = ("curve", "mesh", "points", "signs", "radius", "path", "category")


def check_suite_overrides(cfg: DictConfig, inherited: list[str]) -> None:
    """ConfigError if a command-line override chooses the problem (``data.curve``, ``data.mesh``, ``data.category``,
    …, ``PROBLEM_CHOICE_KEYS``) of a suite whose members solve different problems: every member would then solve
    the same one under its own name (``experiment=fig4 data.curve=circle`` ran the circle six times and labelled the
    rows trefoil, hopf and borromean; ``experiment=table1 data.mesh=…`` would reconstruct one mesh as four parts)."""
    chosen = [o for o in inherited if o.lstrip("+~").split("=", 1)[0] in {f"data.{k}" for k in PROBLEM_CHOICE_KEYS}]
    if not chosen:
        return
    problems = {}
    for member in cfg.suite.runs:
        own = hydra.compose(config_name="train", overrides=member_overrides(member, [], cfg.suite.get("common")))
        problem = {}
        for key in PROBLEM_CHOICE_KEYS:
            value = OmegaConf.select(own, f"data.{key}", default=None)
            if value is not None:
                problem[key] = OmegaConf.to_container(value) if OmegaConf.is_config(value) else value
        problems[str(member.name)] = problem
    if len({repr(sorted(p.items())) for p in problems.values()}) > 1:
        differing = sorted({k for p in problems.values() for k in p
                            if len({repr(q.get(k)) for q in problems.values()}) > 1})
        sets = ", ".join(f"{name}: " + " ".join(f"{k}={p.get(k)}" for k in differing) for name, p in problems.items())
        raise ConfigError(f"{chosen[0]} would choose one problem for the members of this suite, which solve different "
                          f"ones ({sets}), so every member would run the same problem under its own name; run it "
                          "with its own experiment instead (e.g. experiment=minimal_grid, minimal_curve or "
                          "recon_mesh).")


def member_overrides(member: DictConfig, inherited: list[str], common: list[str] | None = None) -> list[str]:
    """A suite member's overrides: the suite's ``common`` ones, its own, then the command line's (Hydra's own
    settings left out), then its ``final_overrides`` (what the member's role fixes whatever the command line says)."""
    return (list(common or []) + list(member.overrides) + [o for o in inherited if not o.startswith("hydra.")]
            + list(member.get("final_overrides") or []))


def compose_members(cfg: DictConfig, inherited: list[str], out_dir: Path) -> dict[str, tuple[list[str], DictConfig]]:
    """Every member's overrides and config, composed and checked before any member trains: a command-line override
    that a member cannot take (``experiment=table1 model.surface_weight=2`` reaches the closest-point baselines,
    which have no such setting) was found only when that member's turn came, after the members before it had
    trained, in Hydra's words or as "a misspelt key". → {name: (overrides, config)}."""
    members = {}
    for member in cfg.suite.runs:
        name, overrides = str(member.name), member_overrides(member, inherited, cfg.suite.get("common"))
        if name in members:
            raise ConfigError(f"The suite names two members {name}; each needs its own name (its folder).")
        try:
            member_cfg = hydra.compose(config_name="train",
                                       overrides=overrides + [f"paths.output_dir={out_dir / name}"])
            validate_config(member_cfg)
            for group in ("model", "data"):
                check_constructor_keys(member_cfg, group)
        except (ConfigError, ConfigCompositionException) as err:
            text = " ".join(str(err).split()).rstrip(".")
            first = str(err).splitlines()[0].rstrip(".")
            if isinstance(err, ConfigCompositionException) and first.startswith(("Could not override",
                                                                                 "Could not delete")):
                text = first + " (this member has no such setting)"  # Hydra's advice to add it with '+' cannot help
            raise ConfigError(f"Suite member {name} cannot run with the command line's overrides "
                              f"({' '.join(inherited) or 'none'}), which reach every member: {text}.") from None
        members[name] = (overrides, member_cfg)
    return members


def check_constructor_keys(cfg: DictConfig, group: str) -> None:
    """ConfigError if ``cfg[group]`` holds a top-level key that its ``_target_``'s constructor does not take (what
    :func:`instantiate` finds when the member is built; found here before any member trains)."""
    node = cfg.get(group)
    target = node.get("_target_") if OmegaConf.is_dict(node) else None
    if target is None:
        return
    params = inspect.signature(hydra.utils.get_class(str(target))).parameters
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
        return
    unknown = [k for k in node if not str(k).startswith("_") and k not in params]
    if unknown:
        owner = str(target).rsplit(".", 1)[-1]
        raise ConfigError(unknown_key_message(node, owner, str(unknown[0]))
                          or f"{group}.{unknown[0]} is not a setting {owner} takes.")


def _leaves(cfg: DictConfig) -> dict[str, str]:
    """A config's settings as {dotted key: repr of the value}, unresolved (interpolations as written)."""
    flat: dict[str, str] = {}

    def walk(value, path: str) -> None:
        if isinstance(value, dict) and value:
            for key, child in value.items():
                walk(child, f"{path}.{key}" if path else str(key))
        else:
            flat[path] = repr(value)

    walk(OmegaConf.to_container(cfg, resolve=False), "")
    flat.pop("paths.output_dir", None)  # the member's own directory
    return flat


def check_suite_variants(cfg: DictConfig, inherited: list[str],
                         members: dict[str, tuple[list[str], DictConfig]]) -> None:
    """ConfigError if the command line's overrides make two members that differ in the suite's own config the same
    run: ``experiment=hand_ablation ablation=relu`` (or ``model.net.activation=relu``) made all five variants the
    ReLU run, and the table and figure labelled them as five."""
    if not any(not o.startswith("hydra.") for o in inherited):
        return
    common = cfg.suite.get("common")
    own = {str(m.name): _leaves(hydra.compose(config_name="train", overrides=member_overrides(m, [], common)))
           for m in cfg.suite.runs}
    given = {name: _leaves(member_cfg) for name, (_, member_cfg) in members.items()}
    set_by_members = {o.lstrip("+~").split("=", 1)[0]
                      for m in cfg.suite.runs for o in member_overrides(m, [], common)}
    names = list(given)
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            if given[a] != given[b] or own[a] == own[b]:
                continue
            keys = sorted(k for k in own[a].keys() | own[b].keys() if own[a].get(k) != own[b].get(k))
            culprits = [o for o in inherited if (key := o.lstrip("+~").split("=", 1)[0]) in set_by_members
                        or any(k == key or k.startswith(key + ".") for k in keys)] or inherited
            shown = ", ".join(f"{k} ({a}: {own[a].get(k, 'unset')}, {b}: {own[b].get(k, 'unset')})" for k in keys[:3])
            raise ConfigError(f"The command line's {' '.join(culprits)} would make suite members {a} and {b} the same "
                              f"run (they differ in {shown}), so the suite would report one variant under two names; "
                              f"run the variant you want with its own experiment instead (e.g. `python train.py "
                              f"{members[a][0][0]} {' '.join(culprits)}`).")


def _member_hint(out_dir: Path, name: str, overrides: list[str]) -> str:
    """How to continue a suite stopped in member ``name``: the suite's command, or this member alone."""
    command = " ".join(shlex.quote(o) for o in [*overrides, "ckpt_path=auto", f"hydra.run.dir={out_dir / name}"])
    suite = (continue_hint(out_dir).rstrip(".") if in_multirun() else
             f"The suite continues with its command and ckpt_path=auto hydra.run.dir={out_dir}")
    return (f"{suite} (each member from its own checkpoint), or this member ({name}) alone with `python train.py "
            f"{command}`.")


def suite_jobs(value: Any, members: int, on_gpu: bool = False) -> int:
    """``suite.jobs``: a positive integer as given; ``auto`` one process per core on a CPU (each trains on one thread,
    its loader worker beside it mostly waiting), one on a GPU (one card: the members one after another); at most
    ``members``."""
    if value == "auto":
        return 1 if on_gpu else max(1, min(members, available_cores()))
    return min(positive_int("suite.jobs", value), max(1, members))


def trains_on_gpu(cfg: DictConfig) -> bool:
    """Whether a run's trainer trains on a GPU (``trainer.accelerator`` gpu or cuda, or auto with CUDA here)."""
    accelerator = str(OmegaConf.select(cfg, "trainer.accelerator", default="auto"))
    return accelerator in ("gpu", "cuda") or accelerator == "auto" and torch.cuda.is_available()


def run_members_in_processes(members: dict[str, tuple[list[str], DictConfig]], out_dir: Path,
                             jobs: int) -> list[dict[str, Any]]:
    """The members in ``jobs`` processes side by side (``python -m deepcurrents.cli.train`` each, its output in
    ``<member>/suite_member.log``); results in the members' order. A member that fails ends the suite with its own
    sentence once the members running beside it have finished; SIGTERM to the suite reaches the running members
    (they checkpoint and stop)."""
    import signal
    import subprocess

    pending = list(members.items())
    running: dict[str, tuple[subprocess.Popen, Any]] = {}
    failed: list[str] = []

    def stop_members(signum, frame):
        for proc, _ in running.values():
            proc.send_signal(signum)
        for proc, _ in running.values():
            proc.wait()
        raise SystemExit(143)

    before = signal.signal(signal.SIGTERM, stop_members)
    try:
        while pending or running:
            while pending and len(running) < jobs and not failed:
                name, (overrides, _) = pending.pop(0)
                member_dir = make_run_dir(out_dir / name)
                log.info("suite member %s (in its own process): %s", name, " ".join(overrides))
                output = open(member_dir / "suite_member.log", "w")  # noqa: SIM115 (closed when the member ends)
                # the cores shared out: torch's own choice in each process would count every core, and jobs × cores
                # threads on the cores wait on each other
                threads = [] if any(o.startswith("torch_threads=") for o in overrides) else \
                    [f"torch_threads={max(1, available_cores() // jobs)}"]
                command = [sys.executable, "-m", "deepcurrents.cli.train", *overrides, *threads,
                           f"hydra.run.dir={member_dir}"]
                running[name] = (subprocess.Popen(command, stdout=output, stderr=subprocess.STDOUT), output)
            if not running:
                break
            time.sleep(0.5)
            for name in [n for n, (proc, _) in running.items() if proc.poll() is not None]:
                proc, output = running.pop(name)
                output.close()
                if proc.returncode != 0:
                    log_file = out_dir / name / "suite_member.log"
                    lines = log_file.read_text(errors="replace").strip().splitlines()
                    why = lines[-1] if lines else f"exit status {proc.returncode}"
                    failed.append(f"Suite member {name} stopped: {why} (its output: {log_file}; "
                                  f"{_member_hint(out_dir, name, members[name][0])})")
                else:
                    log.info("suite member %s finished", name)
    finally:
        signal.signal(signal.SIGTERM, before)
    if failed:
        raise UserInputError(failed[0])
    results = []
    for name, (overrides, _) in members.items():
        path = out_dir / name / "metrics.json"
        metrics = json.loads(path.read_text()) if path.is_file() else {}
        results.append({"name": name, "overrides": overrides, "dir": str(out_dir / name), "metrics": metrics})
    return results


def run_suite(cfg: DictConfig, out_dir: Path, extra_overrides: list[str] | None = None) -> list[dict[str, Any]]:
    """Runs every member of ``cfg.suite`` into ``out_dir/<name>`` and calls the report. → member results.

    A member's ``overrides`` come before the command line's, its ``final_overrides`` after them (what the
    member's role fixes whatever the command line says: Table 1's baseline trains for our run's wall time, so a
    ``trainer.max_steps`` given for the suite must not stop it first)."""
    inherited = inherited_overrides() if extra_overrides is None else list(extra_overrides)
    check_suite_overrides(cfg, inherited)
    members = compose_members(cfg, inherited, out_dir)  # every member checked before the first one trains
    check_suite_variants(cfg, inherited, members)
    if cfg.suite.get("check"):  # the report's own inputs (a stitched body's folder), before any member trains
        hydra.utils.get_method(cfg.suite.check)(cfg)
    jobs = suite_jobs(cfg.suite.get("jobs", 1), len(members), any(trains_on_gpu(c) for _, c in members.values()))
    if jobs > 1:
        results = run_members_in_processes(members, out_dir, jobs)
    else:
        results = []
        for name, (overrides, member_cfg) in members.items():
            member_dir = out_dir / name
            log.info("suite member %s: %s", name, " ".join(overrides))
            metrics = train(member_cfg, out_dir=member_dir, resume_hint=_member_hint(out_dir, name, overrides),
                            member=name, overrides=overrides)
            results.append({"name": name, "overrides": overrides, "dir": str(member_dir), "metrics": metrics or {}})
    (out_dir / "suite.json").write_text(metrics_json(results))
    report = cfg.suite.get("report") or "deepcurrents.experiments.tables.write_table"
    hydra.utils.get_method(report)(out_dir, results, cfg)
    return results
