"""Crashes, preemption and resuming: a run killed (kill -9) or stopped by SIGTERM/SIGUSR1 and resumed with
``ckpt_path=auto`` ends with the weights of the uninterrupted run, bit for bit on the CPU; a checkpoint that
cannot continue this run is refused before training in one sentence; the run directory is checked (writable,
room for checkpoints) and locked against a second run."""

from __future__ import annotations

import errno
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest
import torch
from conftest import (
    QUIET_CPU,
    ROOT,
    TINY_EVAL,
    TINY_NET,
    TRAIN_COMMAND,
    Payload,
    compose_cfg,
    run_command_in_process,
)

from deepcurrents.errors import UserInputError
from deepcurrents.experiments import run_dir
from deepcurrents.experiments.runner import train
from deepcurrents.models.checkpointing import atomic_torch_save

STEPS = 300  # long enough that a signal sent at the first checkpoint arrives well before the end
RUN = ["experiment=minimal_trefoil", *QUIET_CPU, *TINY_NET, *TINY_EVAL, "data.num_samples=512",
       "callbacks.model_checkpoint.every_n_train_steps=5", f"trainer.max_steps={STEPS}"]
ENV = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "HYDRA_FULL_ERROR": "0"}


pytestmark = pytest.mark.usefixtures("one_thread")  # as in the subprocesses (ENV): same reduction order


def weights(path: Path) -> dict[str, torch.Tensor]:
    return torch.load(path, map_location="cpu", weights_only=True)["state_dict"]


def assert_same_weights(a: Path, b: Path) -> None:
    wa, wb = weights(a), weights(b)
    assert wa.keys() == wb.keys()
    different = [k for k in wa if not torch.equal(wa[k], wb[k])]
    assert not different, f"weights differ: {different[:3]}"


def start_cli(args: list[str]) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, str(ROOT / "train.py"), *args], cwd=ROOT, env=ENV,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def wait_for(path: Path, proc: subprocess.Popen, timeout: float = 180) -> None:
    """Short polls until ``path`` exists (the run's first periodic checkpoint)."""
    deadline = time.monotonic() + timeout
    while not path.exists():
        assert proc.poll() is None, f"the run ended before writing {path}: {proc.stderr.read()[-2000:]}"
        assert time.monotonic() < deadline, f"no {path} after {timeout} s"
        time.sleep(0.02)


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory) -> Path:
    """The reference: the same run, never stopped. → its last.ckpt."""
    out = tmp_path_factory.mktemp("uninterrupted")
    metrics = train(compose_cfg(RUN), out_dir=out)
    assert metrics["steps"] == STEPS
    return out / "checkpoints" / "last.ckpt"


@pytest.mark.slow
def test_resumed_in_process_run_equals_the_uninterrupted_one(tmp_path):
    """k < N steps (checkpoint every 2), then ckpt_path=auto to N: the weights, the optimiser's moments and
    the step count equal those of N steps in one go."""
    # the step schedule: preset=cpu's cosine follows the budget, so a run stopped by a smaller max_steps has another
    # learning rate at every step (the kill/signal tests below resume cosine runs with their budget unchanged)
    base = ["experiment=minimal_trefoil", *QUIET_CPU, *TINY_NET, *TINY_EVAL,
            "callbacks.model_checkpoint.every_n_train_steps=2", "model.optim.schedule=step"]
    train(compose_cfg([*base, "trainer.max_steps=7"]), out_dir=tmp_path / "a")
    train(compose_cfg([*base, "trainer.max_steps=3"]), out_dir=tmp_path / "b")
    metrics = train(compose_cfg([*base, "trainer.max_steps=7", "ckpt_path=auto"]), out_dir=tmp_path / "b")
    assert metrics["steps"] == 7
    a, b = tmp_path / "a/checkpoints/last.ckpt", tmp_path / "b/checkpoints/last.ckpt"
    assert_same_weights(a, b)
    ca, cb = (torch.load(p, weights_only=True) for p in (a, b))
    assert ca["global_step"] == cb["global_step"] == 7
    sa, sb = ca["optimizer_states"][0]["state"], cb["optimizer_states"][0]["state"]
    assert all(torch.equal(sa[i]["exp_avg_sq"], sb[i]["exp_avg_sq"]) for i in sa)
    assert ca["lr_schedulers"][0]["last_epoch"] == cb["lr_schedulers"][0]["last_epoch"] == 7


@pytest.mark.slow
def test_kill_9_then_auto_resume_equals_the_uninterrupted_run(tmp_path, uninterrupted):
    out = tmp_path / "run"
    proc = start_cli([*RUN, f"hydra.run.dir={out}"])
    wait_for(out / "checkpoints" / "last.ckpt", proc)
    proc.kill()  # SIGKILL: nothing is written on the way out
    proc.communicate()
    assert proc.returncode == -signal.SIGKILL
    killed_at = torch.load(out / "checkpoints/last.ckpt", weights_only=True)["global_step"]
    assert 0 < killed_at < STEPS and not (out / "metrics.json").exists()
    assert (out / run_dir.LOCK_NAME).exists()  # left behind by the dead process: taken over below
    resumed = train(compose_cfg([*RUN, "ckpt_path=auto"]), out_dir=out)  # in this process: what is on disk counts
    assert resumed["steps"] == STEPS and json.loads((out / "metrics.json").read_text())["steps"] == STEPS
    assert_same_weights(uninterrupted, out / "checkpoints" / "last.ckpt")
    assert not (out / run_dir.LOCK_NAME).exists()


@pytest.mark.slow
@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGUSR1, signal.SIGINT],
                         ids=["SIGTERM", "SIGUSR1", "SIGINT"])
def test_preemption_signal_writes_a_checkpoint_and_resume_reaches_the_same_weights(tmp_path, uninterrupted,
                                                                                   signum):
    """Preemption (SIGTERM, SIGUSR1) and Ctrl-C (SIGINT): the running step ends, last.ckpt holds it, the process
    says how to continue; resuming reaches the uninterrupted run's weights."""
    out = tmp_path / "run"
    proc = start_cli([*RUN, f"hydra.run.dir={out}"])
    wait_for(out / "checkpoints" / "last.ckpt", proc)
    proc.send_signal(signum)
    said, err = proc.communicate(timeout=120)
    assert proc.returncode == (130 if signum == signal.SIGINT else 143), err[-2000:]
    assert "Traceback" not in err and (said + err).count("Continue with ckpt_path=auto") == 1, (said + err)[-2000:]
    stopped_at = torch.load(out / "checkpoints/last.ckpt", weights_only=True)["global_step"]
    assert 0 < stopped_at < STEPS and not (out / "metrics.json").exists()
    assert not (out / run_dir.LOCK_NAME).exists()  # released on the way out
    assert train(compose_cfg([*RUN, "ckpt_path=auto"]), out_dir=out)["steps"] == STEPS
    assert_same_weights(uninterrupted, out / "checkpoints" / "last.ckpt")


@pytest.mark.slow
@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "SIGINT"])
def test_a_signal_to_a_ddp_runs_process_group_stops_it_with_its_checkpoint(tmp_path, signum):
    """trainer=ddp_cpu, the signal sent to the whole process group (a terminal's Ctrl-C, `timeout`, a scheduler):
    the second rank gets SIGTERM twice (from the group and from rank 0's launcher), which hung Lightning's own
    handler; here every rank stops after the same step (a max-reduce of their flags), last.ckpt holds that step
    and the run says once how to continue."""
    out = tmp_path / "run"
    proc = subprocess.Popen([sys.executable, str(ROOT / "train.py"), *RUN, "trainer=ddp_cpu", f"hydra.run.dir={out}"],
                            cwd=ROOT, env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    wait_for(out / "checkpoints" / "last.ckpt", proc)
    first = torch.load(out / "checkpoints/last.ckpt", weights_only=True)["global_step"]
    os.killpg(proc.pid, signum)
    try:
        said, err = proc.communicate(timeout=90)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        pytest.fail("the DDP run hung after the signal")
    assert proc.returncode == (130 if signum == signal.SIGINT else 143), (said + err)[-2000:]
    assert (said + err).count("Continue with ckpt_path=auto") == 1, (said + err)[-2000:]
    stopped = torch.load(out / "checkpoints/last.ckpt", weights_only=True)["global_step"]
    assert first <= stopped < STEPS and not (out / "metrics.json").exists()


LOADER_BOUND = """
import sys, time
import lightning as L, torch
from lightning.pytorch.utilities.exceptions import SIGTERMException
from torch.utils.data import IterableDataset
from deepcurrents.data.ambient import step_loader
from deepcurrents.models.checkpointing import AtomicCheckpointIO, PreemptionCheckpoint

class Slow(IterableDataset):  # the loader, not the step, takes the time: the main process waits on a worker
    def __iter__(self):
        while True:
            time.sleep(0.05)
            yield torch.randn(8, 4)

class Model(L.LightningModule):
    def __init__(self):
        super().__init__()
        self.layer = torch.nn.Linear(4, 1)
    def training_step(self, batch, i):
        if i == 5:
            open(sys.argv[2], "w").close()
        return self.layer(batch).pow(2).mean()
    def configure_optimizers(self):
        return torch.optim.SGD(self.parameters(), 0.01)

stop = PreemptionCheckpoint(sys.argv[1])
trainer = L.Trainer(max_steps=100000, callbacks=[stop], plugins=[AtomicCheckpointIO()], logger=False,
                    enable_progress_bar=False, enable_checkpointing=False, enable_model_summary=False)
try:
    trainer.fit(Model(), step_loader(Slow(), 2, 0))
except SIGTERMException:
    sys.exit(7)  # stopped by the callback, after writing the checkpoint
"""


LIVE_ITERATOR_AT_EXIT = """
import sys, time
import torch
from torch.utils.data import IterableDataset
import deepcurrents.data.ambient as ambient

class Endless(IterableDataset):
    def __iter__(self):
        while True:
            time.sleep(0.01)
            yield torch.zeros(2)

batches = iter(ambient.step_loader(Endless(), 2, 0))
next(batches)
sys.exit(0)  # the iterator still alive: multiprocessing terminates the workers (SIGTERM) and waits for them
"""


def test_loader_workers_still_end_when_terminated_at_exit(tmp_path):
    """Workers outlive a stop signal only for a while, and then end cleanly: a worker ignoring SIGTERM outright hung the
    interpreter's exit whenever a loader iterator was still alive (multiprocessing terminates its children with
    SIGTERM, then waits), and one ended by a signal made PyTorch raise in the main process."""
    script = tmp_path / "live_iterator.py"
    script.write_text(LIVE_ITERATOR_AT_EXIT)
    started = time.monotonic()
    proc = subprocess.run([sys.executable, str(script)], cwd=ROOT, env={**ENV, "DEEPCURRENTS_WORKER_TERM_GRACE": "1"},
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert time.monotonic() - started < 30
    # the workers end cleanly: PyTorch reported one killed by a signal as an exception in the main process
    assert "Traceback" not in proc.stderr and "Exception ignored" not in proc.stderr, proc.stderr[-2000:]


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM, signal.SIGUSR1],
                         ids=["SIGINT", "SIGTERM", "SIGUSR1"])
def test_a_stop_signal_to_the_process_group_spares_loader_workers_and_the_checkpoint(tmp_path, signum):
    """A terminal's Ctrl-C, `timeout`, SLURM's preemption and time-limit signals reach every process of the job,
    loader workers included. They ignore them (data.ambient.step_loader's worker init), so the main process, waiting
    on their next batch, gets it, ends its step and writes last.ckpt (a worker that died of it left the main
    process a RuntimeError and no checkpoint)."""
    script, ckpt, ready = tmp_path / "loader_bound.py", tmp_path / "last.ckpt", tmp_path / "ready"
    script.write_text(LOADER_BOUND)
    proc = subprocess.Popen([sys.executable, str(script), str(ckpt), str(ready)], cwd=ROOT, env=ENV,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    wait_for(ready, proc)
    os.killpg(proc.pid, signum)
    said, err = proc.communicate(timeout=120)
    assert proc.returncode == 7, (said + err)[-2000:]
    assert "exited unexpectedly" not in err and torch.load(ckpt, weights_only=True)["global_step"] > 5


# ------------------------------------------------------------------------------ refused resumes
TINY = ["experiment=minimal_trefoil", *QUIET_CPU, *TINY_NET, *TINY_EVAL, "trainer.max_steps=2"]


@pytest.fixture(scope="module")
def trefoil_ckpt(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("trefoil")
    train(compose_cfg(TINY), out_dir=out)
    return out / "checkpoints" / "last.ckpt"


def refused(tmp_path: Path, overrides: list[str], match: str) -> str:
    cfg = compose_cfg([*TINY, "trainer.max_steps=4", *overrides])
    out = tmp_path / "resumed"
    with pytest.raises(UserInputError, match=match) as info:
        train(cfg, out_dir=out)
    message = str(info.value)
    assert "\n" not in message and message.endswith(".")
    assert not (out / "checkpoints").exists()  # refused before training
    return message


def test_resume_from_missing_truncated_text_or_foreign_files_is_one_sentence(tmp_path, trefoil_ckpt):
    refused(tmp_path, [f"ckpt_path={tmp_path / 'missing.ckpt'}"], "does not exist")
    refused(tmp_path, [f"ckpt_path={tmp_path}"], "is a directory, not a checkpoint file")
    truncated = tmp_path / "truncated.ckpt"
    truncated.write_bytes(trefoil_ckpt.read_bytes()[:3000])
    refused(tmp_path, [f"ckpt_path={truncated}"], "truncated or corrupt")
    text = tmp_path / "notes.ckpt"
    text.write_text("these are my notes, not a checkpoint\n")
    refused(tmp_path, [f"ckpt_path={text}"], "truncated or corrupt")
    foreign = tmp_path / "foreign.ckpt"
    torch.save({"state_dict": {"w": torch.zeros(2)}, "epoch": 0}, foreign)
    refused(tmp_path, [f"ckpt_path={foreign}"], "not written by DeepCurrents")
    plain = tmp_path / "weights.pt"
    torch.save({"w": torch.zeros(2)}, plain)
    refused(tmp_path, [f"ckpt_path={plain}"], "no state_dict")


def test_resume_with_another_model_boundary_or_size_is_one_sentence(tmp_path, trefoil_ckpt):
    ckpt = f"ckpt_path={trefoil_ckpt}"
    refused(tmp_path, [ckpt, "experiment=minimal_grid", "model.grid.resolution=8"],
            "holds a CurrentModule, but this run's config builds a GridModule")
    refused(tmp_path, [ckpt, "data.curve=hopf"], "data.curve='trefoil'.*data.curve='hopf'")
    refused(tmp_path, [ckpt, "data.curve_vertices=60"], "data.curve_vertices=100")
    refused(tmp_path, [ckpt, "model.net.width=8"], "weights do not fit")
    # a recipe that adds a part (the sharpening's buffers) was blamed on the network's sizes
    refused(tmp_path, [ckpt, "recipe=sharp"], r"has no 'current\.sharpening.*a recipe= or model\.\* option")
    # the same setting, another file content: the boundary itself is compared
    curve = tmp_path / "rim.txt"
    t = torch.linspace(0, 2 * torch.pi, 41)[:-1]
    rim = torch.stack([0.5 * torch.cos(t), 0.5 * torch.sin(t), 0 * t], 1)
    curve.write_text("\n".join(" ".join(f"{v:.6f}" for v in row) for row in rim.tolist()))
    first = tmp_path / "first"
    train(compose_cfg([*TINY, "experiment=minimal_curve", f"data.curve={curve}"]), out_dir=first)
    curve.write_text("\n".join(" ".join(f"{v:.6f}" for v in row) for row in (rim * 0.9).tolist()))
    refused(tmp_path, ["experiment=minimal_curve", f"data.curve={curve}",
                       f"ckpt_path={first / 'checkpoints/last.ckpt'}"], "another boundary")


def test_crafted_checkpoint_runs_nothing_on_resume(tmp_path, trefoil_ckpt):
    marker = tmp_path / "MARKER"
    evil = tmp_path / "evil.ckpt"
    ckpt = torch.load(trefoil_ckpt, weights_only=True)
    ckpt["extra"] = Payload(f"touch {marker}")
    torch.save(ckpt, evil)
    message = refused(tmp_path, [f"ckpt_path={evil}"], "could run code")
    assert "posix.system" in message or "os.system" in message
    assert not marker.exists()
    proc = run_command_in_process(TRAIN_COMMAND, [*TINY, "trainer.max_steps=4", f"ckpt_path={evil}",
                                                 f"hydra.run.dir={tmp_path / 'cli'}"], cwd=ROOT)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert [line for line in proc.stderr.splitlines() if line.startswith("error:")][0].count("could run code")
    assert not marker.exists()


def test_cli_resume_errors_exit_2_without_traceback(tmp_path):
    text = tmp_path / "notes.ckpt"
    text.write_text("not a checkpoint\n")
    proc = run_command_in_process(TRAIN_COMMAND, [*TINY, f"ckpt_path={text}", f"hydra.run.dir={tmp_path / 'run'}"],
                                  cwd=ROOT)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    errors = [line for line in proc.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "notes.ckpt" in errors[0] and "truncated or corrupt" in errors[0]


# ------------------------------------------------------------------------------ the run directory
def test_a_refused_run_leaves_the_previous_runs_record_of_its_command(tmp_path):
    """Hydra rewrites the run directory's .hydra/ before any check runs: a refused command into a finished run's
    directory left .hydra/overrides.yaml saying `data.curve=trefoi` beside that run's checkpoint and metrics. The
    command now puts the previous record back when it refuses (status 2)."""
    run_dir = tmp_path / "run"
    done = run_command_in_process(TRAIN_COMMAND, [*TINY, "trainer.max_steps=2", f"hydra.run.dir={run_dir}"], cwd=ROOT)
    assert done.returncode == 0, done.stderr[-2000:]
    record = {p.name: p.read_bytes() for p in (run_dir / ".hydra").iterdir()}
    assert "overrides.yaml" in record
    refused = run_command_in_process(TRAIN_COMMAND, [*TINY, "experiment=minimal_curve", "data.curve=trefoi",
                                                     f"hydra.run.dir={run_dir}"], cwd=ROOT)
    assert refused.returncode == 2 and "trefoi" in refused.stderr
    assert {p.name: p.read_bytes() for p in (run_dir / ".hydra").iterdir()} == record


@pytest.mark.parametrize("where", ["the file", "under the file"])
def test_a_run_directory_that_is_a_file_is_one_sentence_from_the_command_line(tmp_path, where):
    """hydra.run.dir naming a file (or a folder under one) ended in Hydra's FileExistsError traceback, exit 1:
    Hydra makes the folder before our code runs, so the command checks it first."""
    blocker = tmp_path / "a_file"
    blocker.write_text("the user's file")
    run_dir = blocker if where == "the file" else blocker / "run"
    proc = run_command_in_process(TRAIN_COMMAND, [*TINY, f"hydra.run.dir={run_dir}"], cwd=ROOT)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert proc.stderr.strip() == (f"error: hydra.run.dir={run_dir} cannot be made: '{blocker}' is a file, not a "
                                   "folder; choose another run directory.")
    assert blocker.read_text() == "the user's file"


def _refuse_new_files_in(monkeypatch, folder):
    """mkstemp refusing ``folder`` as a read-only folder does (root passes permission bits, so tests cannot chmod)."""
    real = tempfile.mkstemp

    def mkstemp(*args, dir=None, **kwargs):
        if dir is not None and Path(dir) == folder:
            raise PermissionError(errno.EACCES, "Permission denied")
        return real(*args, dir=dir, **kwargs)

    monkeypatch.setattr(tempfile, "mkstemp", mkstemp)


def test_a_read_only_run_directory_is_one_sentence_before_hydra_and_before_training(tmp_path, monkeypatch):
    """A read-only run directory was Hydra's PermissionError traceback (it makes the folder and train.log before our
    code runs), and a read-only checkpoints/ inside a writable one was found after the whole run had trained, with
    the advice to free some space."""
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    _refuse_new_files_in(monkeypatch, run)
    proc = run_command_in_process(TRAIN_COMMAND, [*TINY, f"hydra.run.dir={run}"], cwd=ROOT)
    assert proc.returncode == 2 and proc.stderr.strip() == (
        f"error: hydra.run.dir={run} cannot be written: '{run}' does not take new files (Permission denied); make "
        "it writable or choose another run directory.")
    monkeypatch.undo()
    _refuse_new_files_in(monkeypatch, run / "checkpoints")
    with pytest.raises(UserInputError, match=r"^The output directory '.*checkpoints' cannot be written \(Permission "
                                             r"denied\); make it writable"):
        train(compose_cfg(TINY), out_dir=run)
    assert not list((run / "checkpoints").iterdir())
    with pytest.raises(UserInputError, match=r"could not be written \(Permission denied\); make it writable or"):
        atomic_torch_save({"x": 1}, run / "checkpoints" / "last.ckpt")


def test_a_disk_that_fills_up_under_the_csv_logger_is_one_sentence(tmp_path, monkeypatch):
    """With logger=csv a full disk during training was Lightning's OSError traceback (the checkpoint's own write
    already said it in one sentence)."""
    from lightning.fabric.loggers import csv_logs

    def full(self):
        raise OSError(errno.ENOSPC, "No space left on device", str(tmp_path / "run" / "csv" / "metrics.csv"))

    monkeypatch.setattr(csv_logs._ExperimentWriter, "save", full)
    with pytest.raises(UserInputError, match=r"^Writing the run's files failed at step \d+ \(No space left on device: "
                                             r".*metrics\.csv\); no checkpoint had been written yet; free some space\. "
                                             r"Continue with ckpt_path=auto hydra\.run\.dir=.*run\.$"):
        train(compose_cfg([*TINY, "logger=csv", "trainer.max_steps=3", "trainer.log_every_n_steps=1"]),
              out_dir=tmp_path / "run")


def test_unwritable_or_full_output_directory_stops_before_training(tmp_path, monkeypatch):
    blocker = tmp_path / "a_file"
    blocker.write_text("the user's file")
    with pytest.raises(UserInputError, match="cannot be written") as info:
        train(compose_cfg(TINY), out_dir=blocker / "run")
    assert "\n" not in str(info.value) and blocker.read_text() == "the user's file"

    class Usage:
        total, used, free = 10**9, 10**9 - 1000, 1000  # a full disk: 1000 bytes left

    monkeypatch.setattr(run_dir.shutil, "disk_usage", lambda path: Usage)
    with pytest.raises(UserInputError, match=r"has 0\.0 MB free, but this run needs about"):
        train(compose_cfg(TINY), out_dir=tmp_path / "full")
    assert not (tmp_path / "full" / "checkpoints").exists()


def test_a_second_run_into_a_locked_directory_is_refused_and_stale_locks_are_taken_over(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    lock = out / run_dir.LOCK_NAME
    import socket

    # a live process (this test's parent) holds the directory
    lock.write_text(json.dumps({"host": socket.gethostname(), "pid": os.getppid(), "slurm_job": None}))
    with pytest.raises(UserInputError, match=f"in use by process {os.getppid()}"):
        train(compose_cfg(TINY), out_dir=out)
    assert lock.exists() and not (out / "checkpoints").exists()
    # a process that is gone: its lock is taken over, and released at the end
    gone = subprocess.Popen(["true"])
    gone.wait()
    lock.write_text(json.dumps({"host": socket.gethostname(), "pid": gone.pid, "slurm_job": None}))
    assert train(compose_cfg(TINY), out_dir=out)["steps"] == 2
    assert not lock.exists()


def test_lock_is_held_during_training(tmp_path, monkeypatch):
    """While a run trains, its directory's lock names this process (checked from inside a training step)."""
    seen = []
    from deepcurrents.models import current_module

    original = current_module.CurrentModule.training_step

    def spy(self, batch, batch_idx):
        seen.append(json.loads((tmp_path / run_dir.LOCK_NAME).read_text())["pid"])
        return original(self, batch, batch_idx)

    monkeypatch.setattr(current_module.CurrentModule, "training_step", spy)
    train(compose_cfg(TINY), out_dir=tmp_path)
    assert seen == [os.getpid(), os.getpid()] and not (tmp_path / run_dir.LOCK_NAME).exists()


def test_auto_without_a_checkpoint_starts_fresh_and_requeued_slurm_jobs_resume(tmp_path, monkeypatch):
    assert run_dir.resume_path("auto", tmp_path) is None
    assert run_dir.resume_path(None, tmp_path) is None
    (tmp_path / "checkpoints").mkdir()
    older, newer = tmp_path / "checkpoints/step0000005.ckpt", tmp_path / "hpc_ckpt_1.ckpt"
    older.write_bytes(b"x")
    newer.write_bytes(b"x")
    os.utime(older, ns=(1_000_000_000, 1_000_000_000))
    assert run_dir.resume_path("auto", tmp_path) == newer
    assert run_dir.resume_path(None, tmp_path) == newer  # Lightning's SLURM checkpoint: resumed, and checked
    newer.unlink()
    assert run_dir.resume_path(None, tmp_path) is None  # a fresh run does not resume by itself
    monkeypatch.setenv("SLURM_RESTART_COUNT", "1")  # a requeued job does
    assert run_dir.resume_path(None, tmp_path) == older


def test_each_batch_is_a_function_of_seed_rank_and_step_whatever_the_workers():
    """Batch s is the same with 0 or 2 loader workers and when the stream starts at s (a resumed run)."""
    from torch.utils.data import DataLoader

    from deepcurrents.data import AmbientSamples

    def batches(start: int, workers: int, count: int) -> list[torch.Tensor]:
        loader = DataLoader(AmbientSamples(3, 16, seed=7, rank=1, start_step=start), batch_size=None,
                            num_workers=workers)
        stream = iter(loader)
        return [next(stream)["x"] for _ in range(count)]

    serial = batches(0, 0, 6)
    assert all(torch.equal(a, b) for a, b in zip(serial, batches(0, 2, 6), strict=True))
    assert all(torch.equal(a, b) for a, b in zip(serial[3:], batches(3, 0, 3), strict=True))
    assert not torch.equal(serial[0], serial[1])
    other_rank = next(iter(AmbientSamples(3, 16, seed=7, rank=0)))["x"]
    assert not torch.equal(serial[0], other_rank)


def test_resume_compares_data_files_not_how_they_were_written(tmp_path):
    """data.path written with a trailing slash, through a symlink, relative, or as the list of the folder's meshes
    names the same files: resuming with any of them was refused ('was trained with data.path=…/fam, but this run
    has …/fam/'). A folder with other files, or a named curve against a file, still differs."""
    from deepcurrents.models.loading import _files, _same

    fam = tmp_path / "fam"
    fam.mkdir()
    for name in ("000.ply", "001.obj", "notes.txt"):
        (fam / name).write_text("x")
    (tmp_path / "link").symlink_to(fam)
    meshes = [str(fam / "000.ply"), str(fam / "001.obj")]
    ways = [str(fam), str(fam) + "/", str(tmp_path / "link"), meshes, list(reversed(meshes))[::-1]]
    assert all(_same(_files(ways[0]), _files(w)) for w in ways)
    assert not _same(_files(str(fam)), _files([meshes[0]]))
    assert _files("trefoil") == "trefoil" and _files(None) is None


def test_the_slurm_launcher_off_a_cluster_is_one_sentence(tmp_path, monkeypatch):
    """hydra/launcher=submitit_slurm where no srun is found ended in submitit's RuntimeError traceback."""
    import shutil

    monkeypatch.setattr(shutil, "which", lambda name: None)
    proc = run_command_in_process(TRAIN_COMMAND, ["-m", *TINY, "hydra/launcher=submitit_slurm",
                                                  f"hydra.sweep.dir={tmp_path / 'sweep'}"], cwd=ROOT)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert proc.stderr.strip().startswith("error: hydra/launcher=submitit_slurm submits to SLURM, but `srun` is not")
    assert not (tmp_path / "sweep").exists()
