"""The run directory's safety: it can be written and has room for the checkpoints (checked before training),
only one run writes into it at a time (a lock file), and ``ckpt_path=auto`` finds its newest checkpoint.

The lock is ``<run dir>/.deepcurrents.lock`` holding the owner's host, process id and SLURM job id. A second
run into the same directory is refused with one sentence while the owner lives; a lock left by a process that
died (``kill -9``, a node failure) is taken over: same host and the process is gone, or the same SLURM job
(a requeued job restarts under its old job id, possibly on another node).
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import socket
import tempfile
from pathlib import Path

import torch

from deepcurrents.errors import UserInputError

log = logging.getLogger("deepcurrents")

LOCK_NAME = ".deepcurrents.lock"
MB = 1024 * 1024


def is_global_rank_zero() -> bool:
    """True unless the environment names this process a non-zero DDP rank (Lightning's launcher and SLURM set
    these variables for every rank; the ranks of one run share its directory and its lock)."""
    for key in ("RANK", "SLURM_PROCID", "LOCAL_RANK", "NODE_RANK"):
        value = os.environ.get(key)
        if value not in (None, "", "0"):
            return False
    return True


def writable_problem(folder: Path) -> str | None:
    """Why files cannot be written in ``folder`` (an existing folder), or None: a file is made and removed there,
    since permission bits do not tell (root passes them; an immutable folder or a read-only mount does not)."""
    try:
        fd, probe = tempfile.mkstemp(prefix=".write-test.", dir=folder)
        os.close(fd)
        os.unlink(probe)
    except OSError as err:
        return err.strerror or type(err).__name__
    return None


def make_run_dir(out_dir: Path) -> Path:
    """Creates ``out_dir`` and checks that files can be written there and in its ``checkpoints/`` (if it exists
    already: a resumed or reused run directory), or one sentence saying why not."""
    problem, where = None, out_dir
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        problem = err.strerror or type(err).__name__
    for where in (out_dir, out_dir / "checkpoints"):
        problem = problem or (writable_problem(where) if where.is_dir() else None)
        if problem is not None:
            break
    if problem is not None:
        raise UserInputError(f"The output directory '{where}' cannot be written ({problem}); make it writable or "
                             "choose another with hydra.run.dir=… (or paths.output_dir=…).")
    return out_dir


def checkpoint_bytes(module: torch.nn.Module) -> int:
    """About the size of one checkpoint: the weights and buffers, and Adam's two moments per trainable weight."""
    weights = sum(t.numel() * t.element_size() for t in module.state_dict().values())
    moments = 2 * sum(p.numel() * p.element_size() for p in module.parameters() if p.requires_grad)
    return weights + moments


def check_free_space(out_dir: Path, module: torch.nn.Module, margin: int = 32 * MB) -> None:
    """Refuses to start when ``out_dir`` cannot hold two checkpoints (an atomic write keeps the old one until
    the new one is complete) and ``margin`` for meshes, pictures and metrics."""
    need = 2 * checkpoint_bytes(module) + margin
    free = shutil.disk_usage(out_dir).free
    if free < need:
        raise UserInputError(
            f"The output directory '{out_dir}' has {free / MB:.1f} MB free, but this run needs about "
            f"{need / MB:.1f} MB for its checkpoints and results; free some space or choose another with "
            "hydra.run.dir=…."
        )


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by someone else
        return True
    return True


class RunLock:
    """``with RunLock(out_dir):`` — this process alone writes the run directory's checkpoints (see the module's
    docstring). Released when the block ends, whatever ends it."""

    def __init__(self, out_dir: Path):
        self.path = Path(out_dir) / LOCK_NAME
        self.owner = {"host": socket.gethostname(), "pid": os.getpid(),
                      "slurm_job": os.environ.get("SLURM_JOB_ID")}
        self.held = False

    def _stale(self, other: dict) -> bool:
        if self.owner["slurm_job"] and other.get("slurm_job") == self.owner["slurm_job"]:
            return True  # our own job before it was requeued
        return other.get("host") == self.owner["host"] and not _alive(int(other.get("pid", -1)))

    def acquire(self) -> None:
        for _ in range(3):  # a race with another starter: retry after taking over a stale lock
            try:
                fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            except FileExistsError:
                try:
                    other = json.loads(self.path.read_text())
                except (OSError, ValueError):
                    other = {}
                if other.get("pid") == self.owner["pid"] and other.get("host") == self.owner["host"]:
                    return  # this process holds it already (a suite member in a subdirectory has its own)
                if other and not self._stale(other):
                    raise UserInputError(
                        f"The run directory '{self.path.parent}' is in use by process {other.get('pid')} on "
                        f"{other.get('host')}; wait for that run to end or choose another directory with "
                        f"hydra.run.dir=… (if that run is gone, delete {self.path})."
                    ) from None
                log.warning("Taking over the lock %s left by process %s on %s, which is gone.", self.path,
                            other.get("pid"), other.get("host"))
                self.path.unlink(missing_ok=True)
                continue
            with os.fdopen(fd, "w") as fh:
                json.dump(self.owner, fh)
            self.held = True
            return
        raise UserInputError(f"The run directory '{self.path.parent}' is being locked by another run at the same "
                             "time; start one run per directory.")

    def release(self) -> None:
        if self.held:
            self.path.unlink(missing_ok=True)
            self.held = False

    def __enter__(self) -> RunLock:
        self.acquire()
        return self

    def __exit__(self, *exc) -> None:
        self.release()


def newest_checkpoint(out_dir: Path) -> Path | None:
    """The most recently written checkpoint of a run directory: ``checkpoints/*.ckpt`` (periodic and
    ``last.ckpt``) or Lightning's SLURM ``hpc_ckpt_*.ckpt``; None if there is none."""
    found = [p for p in [*Path(out_dir).glob("checkpoints/*.ckpt"), *Path(out_dir).glob("hpc_ckpt_*.ckpt")]
             if p.is_file()]
    return max(found, key=lambda p: p.stat().st_mtime_ns) if found else None


def resume_path(ckpt_path: str | None, out_dir: Path) -> Path | None:
    """The checkpoint a run resumes from. ``ckpt_path``: a file; ``auto``: the newest checkpoint in the run
    directory, or a fresh start if it has none (what a cluster job that may be requeued passes); None: a
    fresh start, except in a requeued SLURM job (SLURM_RESTART_COUNT > 0) or a directory holding Lightning's
    SLURM ``hpc_ckpt_*.ckpt`` (which Lightning would load by itself, unchecked), which resume like ``auto``."""
    if ckpt_path is None:
        requeued = int(os.environ.get("SLURM_RESTART_COUNT", "0") or 0) > 0
        if not requeued and not any(Path(out_dir).glob("hpc_ckpt_*.ckpt")):
            return None
        ckpt_path = "auto"
    if str(ckpt_path) == "auto":
        found = newest_checkpoint(out_dir)
        if is_global_rank_zero():  # said once, not by every DDP rank
            if found is None:
                log.info("ckpt_path=auto: no checkpoint in %s yet; starting from step 0.", out_dir)
            else:
                log.info("ckpt_path=auto: resuming from %s.", found)
        return found
    return Path(str(ckpt_path)).expanduser()
