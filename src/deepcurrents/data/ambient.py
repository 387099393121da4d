"""Samples of the domain U = [-1, 1]^d (uniform by default; see data.sampling) and the DataModule for minimal
surfaces."""

from __future__ import annotations

import functools
import os
import signal
from collections.abc import Iterator, Sequence

import lightning as L
import numpy as np
import torch
from lightning.fabric.utilities.seed import pl_worker_init_function
from torch.utils.data import DataLoader, IterableDataset, get_worker_info

from deepcurrents.data.sampling import AmbientSampler, cell_scores, pool_batch, sample_pool, sampling_options
from deepcurrents.errors import ConfigError
from deepcurrents.geometry import Boundary, PointBoundary, biot_savart, biot_savart_2d, load_boundary, validate_points


def stream_seed(seed: int, rank: int, step: int) -> int:
    """A distinct, reproducible seed per (run seed, DDP rank, training step)."""
    return int(np.random.SeedSequence([seed, rank, step]).generate_state(1)[0])


def step_generators(seed: int, rank: int, start_step: int) -> Iterator[tuple[int, torch.Generator]]:
    """(step, generator) for the batches this loader worker makes: a DataLoader over an IterableDataset takes
    batches from its workers in turn, so worker w of W makes those of steps start_step + w + j·W. Each batch
    has its own generator, seeded by (seed, rank, step) alone: a run resumed at step k draws exactly the
    batches the uninterrupted run drew from step k on, whatever the number of workers."""
    info = get_worker_info()
    worker, workers = (info.id, info.num_workers) if info is not None else (0, 1)
    step = start_step + worker
    while True:
        yield step, torch.Generator().manual_seed(stream_seed(seed, rank, step))
        step += workers


# seconds a loader worker lives on after SIGTERM (see loader_worker_init); DEEPCURRENTS_WORKER_TERM_GRACE overrides
WORKER_TERM_GRACE = 60


def _end_after_grace(signum: int, frame) -> None:
    remaining = signal.alarm(0)
    signal.alarm(remaining or int(os.environ.get("DEEPCURRENTS_WORKER_TERM_GRACE", WORKER_TERM_GRACE)))


def _end_now(signum: int, frame) -> None:
    # a clean exit: PyTorch's SIGCHLD handler in the main process raises wherever it is for a worker killed by a signal
    os._exit(0)


def loader_worker_init(worker_id: int, rank: int = 0) -> None:
    """A loader worker outlives the signals that stop a run, which a terminal, `timeout` or SLURM send to every
    process of the job: the main process stops after its running step and writes a checkpoint
    (models.checkpointing.PreemptionCheckpoint), and a worker that died of the signal would leave that step without
    its batch (PyTorch would even raise in the main process at once). Ctrl-C and SIGUSR1 are ignored (the workers end
    with the main process); SIGTERM ends the worker ``WORKER_TERM_GRACE`` seconds after the first one, not never,
    because multiprocessing ends the workers of a loader still alive at exit with SIGTERM and then waits for them.
    Seeds the worker as Lightning would (``seed_everything(workers=True)``), whose own init function a loader with
    one does not get."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if hasattr(signal, "SIGUSR1"):
        signal.signal(signal.SIGUSR1, signal.SIG_IGN)
    if hasattr(signal, "SIGALRM"):
        signal.signal(signal.SIGALRM, _end_now)
        signal.signal(signal.SIGTERM, _end_after_grace)
    if int(os.environ.get("PL_SEED_WORKERS", 0)):
        pl_worker_init_function(worker_id, rank=rank)


def step_loader(dataset: IterableDataset, num_workers: int, rank: int) -> DataLoader:
    """The DataLoader of a stream of whole batches (``batch_size=None``; one batch a training step), its workers
    kept alive between epochs and outliving the stop signals a while (``loader_worker_init``)."""
    init = functools.partial(loader_worker_init, rank=rank) if num_workers > 0 else None
    return DataLoader(dataset, batch_size=None, num_workers=num_workers, persistent_workers=num_workers > 0,
                      worker_init_fn=init)


class AmbientSamples(IterableDataset):
    """An endless stream of batches {"x": (num_samples, dim)} of [-1, 1]^dim: uniform by default, or from
    ``sampling`` (AmbientSampler keyword arguments: Sobol points, or importance samples that also carry
    "weight": (num_samples,), 1 / (vol(U)·density), so that the weighted loss is still the uniform mean).

    The batch of step s is a function of (seed, rank, s) (:func:`step_generators`): each DDP rank draws its
    own samples, and a run resumed at ``start_step`` continues with the batches an uninterrupted run draws.
    """

    def __init__(self, dim: int, num_samples: int, seed: int = 0, rank: int = 0, start_step: int = 0,
                 sampling: dict | None = None, pool: dict[str, torch.Tensor] | None = None):
        self.dim, self.num_samples = dim, num_samples
        self.seed, self.rank, self.start_step = seed, rank, start_step
        self.sampling = {k: v for k, v in (sampling or {}).items() if k != "pool"}
        self.pool = pool  # precomputed samples with their α (data.sampling.pool): batches are drawn from it

    def __iter__(self) -> Iterator[dict[str, torch.Tensor]]:
        if self.pool is not None:
            for _, gen in step_generators(self.seed, self.rank, self.start_step):
                yield pool_batch(self.pool, self.num_samples, gen)
            return
        uniform = self.sampling.get("kind", "uniform") == "uniform"
        sampler = None if uniform else AmbientSampler(self.dim, seed=self.seed, **self.sampling)
        for _, gen in step_generators(self.seed, self.rank, self.start_step):
            if sampler is None:
                yield {"x": torch.rand(self.num_samples, self.dim, generator=gen) * 2.0 - 1.0}
                continue
            # the sampler's own streams restart at this step's seed (a fresh scrambling for Sobol)
            step_seed = int(torch.randint(2**62, (1,), generator=gen))
            sampler.generator = gen
            if sampler.sobol is not None:
                sampler.sobol = torch.quasirandom.SobolEngine(self.dim, scramble=True, seed=step_seed)
            yield sampler.sample(self.num_samples)


class MinimalSurfaceDataModule(L.LightningDataModule):
    """Boundary Γ (validated at construction, so bad input stops before training) and ambient samples.

    3D: ``curve`` is a named curve (trefoil, hopf, borromean, circle, enneper) or a curve file, times
    ``curve_scale``. ``normalize`` (auto/true/false) centres and scales it into the box when it reaches
    beyond the safe extent or is small (``geometry.curves.SAFE_EXTENT``, ``SMALL_EXTENT``; the Boundary keeps
    the map back to the input's coordinates); loops with more than ``max_vertices_per_loop`` vertices are
    resampled by arc length.
    2D: ``points`` [[x, y], ...] with ``signs`` [±1, ...].
    """

    def __init__(
        self,
        dim: int = 3,
        curve: str = "trefoil",
        curve_vertices: int = 100,
        curve_scale: float = 1.0,
        normalize: bool | str = "auto",
        max_vertices_per_loop: int | None = 512,
        points: Sequence[Sequence[float]] | None = None,
        signs: Sequence[float] | None = None,
        num_samples: int = 4096,
        num_workers: int = 0,
        seed: int = 0,
        sampling: dict | None = None,
    ):
        super().__init__()
        self.sampling = sampling_options(sampling)  # the settings are checked before anything is built (schema)
        self.dim, self.num_samples, self.num_workers, self.seed = dim, num_samples, num_workers, seed
        self.boundary: Boundary | PointBoundary
        if dim == 3:
            if curve is None:  # experiment=minimal_curve without its file
                raise ConfigError("data.curve must be given: a named curve (trefoil, hopf, borromean, circle, "
                                  "enneper) or a curve file, e.g. data.curve=path/to/rim.obj.")
            self.boundary = load_boundary(curve, n=curve_vertices, scale=curve_scale, normalize=normalize,
                                          max_vertices=max_vertices_per_loop)
        else:
            if points is None or signs is None:
                raise ConfigError("data.points and data.signs are required for a 2D run (data.dim=2).")
            self.boundary = validate_points(points, signs)
        AmbientSampler(dim, **{k: v for k, v in self.sampling.items() if k != "pool"})  # checks the options
        if self.sampling.get("kind") == "importance":
            self.sampling["scores"] = cell_scores(self.alpha_field(), dim, int(self.sampling.get("resolution", 16)),
                                                  seed=self.seed)
        self._pool: dict[str, torch.Tensor] | None = None

    def alpha_field(self):
        """x ↦ α_Γ(x), unscaled (the current multiplies it by alpha_scale). (N, dim) → (N, dim)."""
        if self.dim == 3:
            loops = [torch.as_tensor(lp, dtype=torch.float32) for lp in self.boundary.loops]
            return lambda x: biot_savart(x, loops)
        poles = torch.as_tensor(self.boundary.points, dtype=torch.float32)
        signs = torch.as_tensor(self.boundary.signs, dtype=torch.float32)
        return lambda x: biot_savart_2d(x, poles, signs)

    def sample_pool(self) -> dict[str, torch.Tensor] | None:
        """The data.sampling.pool samples with α precomputed (built once, on first use), or None."""
        if self.sampling["pool"] and self._pool is None:
            options = {k: v for k, v in self.sampling.items() if k != "pool"}
            sampler = AmbientSampler(self.dim, seed=self.seed, **options)  # one pool for every rank
            self._pool = sample_pool(sampler, self.sampling["pool"], self.alpha_field())
        return self._pool

    def train_dataloader(self) -> DataLoader:
        trainer = self.trainer
        rank = trainer.global_rank if trainer is not None else 0
        start = trainer.global_step if trainer is not None else 0
        dataset = AmbientSamples(self.dim, self.num_samples, self.seed, rank, start, self.sampling,
                                 pool=self.sample_pool())
        return step_loader(dataset, self.num_workers, rank)
