"""Checkpoints: written atomically (temporary file + rename, so a crash never leaves a torn file), holding only
tensors and plain data (so they are read with ``torch.load(..., weights_only=True)``, which never runs code
from the file), and carrying what an exact resume needs beyond Lightning's own state (the random generators).

- :class:`AtomicCheckpointIO`: Lightning's checkpoint IO with atomic writes, plain data checked on saving,
  and safe reads on resuming (``trainer.fit(ckpt_path=…)`` and SLURM's ``hpc_ckpt_*.ckpt`` both read here).
- :class:`ResumeState`: a callback saving the global random generators (torch, CUDA, numpy, Python) in every
  checkpoint and restoring them before the first step of a resumed run.
- :class:`PreemptionCheckpoint`: a callback writing ``last.ckpt`` when the run is stopped by SIGTERM or SIGUSR1
  (SLURM preemption, ``scancel``, a time limit) or Ctrl-C, so that a requeued job continues from the step it reached.
"""

from __future__ import annotations

import errno
import logging
import os
import random
import signal
import tempfile
import threading
from pathlib import Path
from typing import Any

import lightning as L
import numpy as np
import torch
from lightning.pytorch.plugins.io import TorchCheckpointIO
from lightning.pytorch.utilities.exceptions import SIGTERMException

from deepcurrents.errors import UserInputError

log = logging.getLogger("deepcurrents")

PLAIN_SCALARS = (str, int, float, bool, type(None))


def plain_data(obj: Any, where: str = "checkpoint") -> Any:
    """``obj`` with every container made a dict/list/tuple and every leaf a tensor, str, number, bool or None
    (what ``torch.load(weights_only=True)`` accepts): OmegaConf containers become dicts and lists, numpy
    arrays tensors, numpy scalars Python numbers, paths strings. Any other object is a programming error
    (TypeError naming where it sits), caught by the tests that save every model kind."""
    if isinstance(obj, torch.Tensor) or isinstance(obj, PLAIN_SCALARS):
        return obj
    if isinstance(obj, dict):
        return {k: plain_data(v, f"{where}[{k!r}]") for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        items = [plain_data(v, f"{where}[{i}]") for i, v in enumerate(obj)]
        return tuple(items) if isinstance(obj, tuple) and not hasattr(obj, "_fields") else items
    if isinstance(obj, np.ndarray):
        return torch.from_numpy(np.ascontiguousarray(obj))
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    from omegaconf import DictConfig, ListConfig, OmegaConf

    if isinstance(obj, (DictConfig, ListConfig)):
        return plain_data(OmegaConf.to_container(obj, resolve=True), where)
    raise TypeError(f"{where} holds a {type(obj).__module__}.{type(obj).__qualname__}; checkpoints hold only "
                    "tensors and plain data (convert it in on_save_checkpoint or state_dict).")


def current_umask() -> int:
    """The process's file-creation mask: from /proc/self/status on Linux, which leaves it untouched; elsewhere by
    setting it and putting it back (a file another thread creates in between would get 022)."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except OSError:
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def kept_checkpoint(trainer: L.Trainer | None) -> str:
    """Where a stopped run's last good checkpoint is, as the end of a sentence: "the last good checkpoint is kept in
    DIR", or "no checkpoint had been written yet" (a run stopped before its first one)."""
    kept = [cb.dirpath for cb in (trainer.checkpoint_callbacks if trainer is not None else [])
            if cb.dirpath and any(Path(cb.dirpath).glob("*.ckpt"))]
    return f"the last good checkpoint is kept in {kept[0]}" if kept else "no checkpoint had been written yet"


def atomic_torch_save(obj: Any, path: str | Path) -> None:
    """torch.save into a temporary file in the same directory, fsync, then os.replace onto ``path``."""
    path = Path(path)
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
        if hasattr(os, "fchmod"):  # mkstemp's 0600 would outlive the rename: the mode any new file gets here
            os.fchmod(fd, 0o666 & ~current_umask())
        with os.fdopen(fd, "wb") as fh:
            torch.save(obj, fh)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException as err:
        if tmp is not None and os.path.exists(tmp):
            os.unlink(tmp)
        if isinstance(err, OSError):  # a full disk or a vanished directory in the middle of a run
            kept = " (the previous one is kept)" if path.exists() else ""
            advice = "free some space" if err.errno in (errno.ENOSPC, errno.EDQUOT) else "make it writable"
            raise UserInputError(f"The checkpoint {path} could not be written ({err.strerror or type(err).__name__})"
                                 f"{kept}; {advice} or choose another hydra.run.dir.") from None
        raise


class AtomicCheckpointIO(TorchCheckpointIO):
    """Lightning checkpoint IO: atomic writes of plain data, reads that never unpickle arbitrary objects."""

    def save_checkpoint(self, checkpoint: dict[str, Any], path, storage_options=None) -> None:
        atomic_torch_save(plain_data(checkpoint), path)

    def load_checkpoint(self, path, map_location=None, weights_only: bool | None = None) -> dict[str, Any]:
        # whatever the caller asks: a checkpoint is data, never code (the runner has already checked the
        # file with models.loading.read_checkpoint, which explains a refusal in one sentence)
        return super().load_checkpoint(path, map_location=map_location, weights_only=True)


def random_state() -> dict[str, Any]:
    """The global random generators' states as tensors and plain data."""
    kind, keys, pos, has_gauss, cached = np.random.get_state()
    state = {
        "torch": torch.get_rng_state(),
        "numpy": {"kind": kind, "keys": torch.from_numpy(keys.astype(np.int64)), "pos": int(pos),
                  "has_gauss": int(has_gauss), "cached_gaussian": float(cached)},
        "python": random.getstate(),
    }
    if torch.cuda.is_available() and torch.cuda.is_initialized():
        state["cuda"] = torch.cuda.get_rng_state_all()
    return state


def set_random_state(state: dict[str, Any]) -> None:
    """Restores what :func:`random_state` returned."""
    torch.set_rng_state(state["torch"])
    npy = state["numpy"]
    np.random.set_state((npy["kind"], npy["keys"].numpy().astype(np.uint32), npy["pos"], npy["has_gauss"],
                         npy["cached_gaussian"]))
    version, internal, gauss = state["python"]
    random.setstate((version, tuple(internal), gauss))
    if "cuda" in state and torch.cuda.is_available():
        states = state["cuda"]
        if len(states) == torch.cuda.device_count():
            torch.cuda.set_rng_state_all(states)


class ResumeState(L.Callback):
    """Saves the global random generators with every checkpoint and puts them back right before the first
    training step of a resumed run (after the setup that may draw numbers of its own), so that a resumed run
    draws what the uninterrupted run drew. Batches come from per-step streams (data.ambient.step_generators)."""

    def __init__(self) -> None:
        self._pending: dict[str, Any] | None = None

    def state_dict(self) -> dict[str, Any]:
        return {"random": random_state()}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        self._pending = state_dict.get("random")

    def on_train_batch_start(self, trainer: L.Trainer, pl_module: L.LightningModule, batch: Any,
                             batch_idx: int) -> None:
        if self._pending is not None:
            set_random_state(self._pending)
            self._pending = None


class PreemptionCheckpoint(L.Callback):
    """On SIGTERM (preemption, ``scancel``), SIGUSR1 (the signal SLURM sends ahead of a time limit with
    ``--signal=USR1@90``; handled here unless Lightning's own SLURM auto-requeue handler has it) or Ctrl-C (SIGINT;
    a second Ctrl-C stops a single process at once, without a checkpoint; one while the checkpoint is written
    waits for it), writes ``path`` (the run's ``checkpoints/last.ckpt``) after the running step and stops with
    SIGTERMException; ``signal_name`` says which signal. Other exceptions write nothing: after a NaN loss the last
    good checkpoint must stay.

    Under DDP every rank stops after the same step: the ranks' flags are max-reduced at the end of each step (one
    tiny collective), and SIGTERM is handled here instead of by Lightning, whose handler broadcasts from inside
    the signal handler and hung a two-process run whose second rank got the signal twice (from the process group
    and from rank 0's launcher)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.saved_step: int | None = None
        self.signal_name = "SIGTERM"
        self._stop = False
        self._saving = False
        self._presses = 0
        self._distributed = False
        self._previous: dict[int, Any] = {}

    def _on_signal(self, signum: int, frame: Any) -> None:
        if signum == signal.SIGINT:
            if self._saving:  # the checkpoint is being written: an interruption now would only lose it
                log.warning("Ctrl-C: the checkpoint is being written; a moment.")
                return
            self._presses += 1
            # pressed again: the user does not want to wait for the step. Under DDP only the third press (one rank
            # leaving mid-step stops the others through Lightning's launcher, but a second press is often just
            # impatience while every rank finishes its step)
            if self._stop and self._presses >= (3 if self._distributed else 2):
                raise KeyboardInterrupt
            again = "a third Ctrl-C" if self._distributed else "Ctrl-C again"
            log.warning("Ctrl-C: stopping after this step and writing the checkpoint (%s stops at once, losing the "
                        "steps since the last checkpoint).", again)
        if not self._stop:
            self.signal_name = signal.Signals(signum).name
        self._stop = True  # acted on at the end of the running step

    def _take(self, signum: int) -> None:
        self._previous[signum] = signal.signal(signum, self._on_signal)

    def on_train_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self._stop, self._presses = False, 0  # a callback used for a second fit starts afresh
        if threading.current_thread() is not threading.main_thread():
            return
        self._distributed = trainer.world_size > 1 and torch.distributed.is_available() \
            and torch.distributed.is_initialized()
        usr1 = getattr(signal, "SIGUSR1", None)
        if usr1 is not None and signal.getsignal(usr1) in (signal.SIG_DFL, None):
            self._take(usr1)
        if signal.getsignal(signal.SIGINT) is signal.default_int_handler:  # not where a caller handles Ctrl-C
            self._take(signal.SIGINT)
        if self._distributed:
            self._take(signal.SIGTERM)

    def on_train_batch_end(self, trainer: L.Trainer, pl_module: L.LightningModule, outputs: Any, batch: Any,
                           batch_idx: int) -> None:
        stop = self._stop
        if self._distributed:  # one rank's signal stops them all, after this same step
            flag = torch.tensor([float(stop)], device=trainer.strategy.root_device)
            torch.distributed.all_reduce(flag, op=torch.distributed.ReduceOp.MAX)
            stop = bool(flag.item())
            if stop and not self._stop:
                self.signal_name, self._stop = "a signal to another rank", True
        if stop:
            raise SIGTERMException()

    def teardown(self, trainer: L.Trainer, pl_module: L.LightningModule, stage: str) -> None:
        for signum, previous in self._previous.items():
            if signal.getsignal(signum) == self._on_signal:  # unless another hand has set it since
                signal.signal(signum, previous)
        self._previous = {}

    def on_exception(self, trainer: L.Trainer, pl_module: L.LightningModule, exception: BaseException) -> None:
        if isinstance(exception, SIGTERMException):
            self._saving = True
            try:
                trainer.save_checkpoint(self.path, weights_only=False)
            finally:
                self._saving = False
            self.saved_step = int(trainer.global_step)
            if trainer.is_global_zero:
                log.info("Stopped by %s at step %d; checkpoint written to %s.", self.signal_name, self.saved_step,
                         self.path)
