"""Uniform samples of the domain U = [-1, 1]^d and the DataModule for minimal surfaces."""

from __future__ import annotations

from collections.abc import Iterator, Sequence

import lightning as L
import numpy as np
import torch
from torch.utils.data import DataLoader, IterableDataset, get_worker_info

from deepcurrents.errors import ConfigError
from deepcurrents.geometry import Boundary, PointBoundary, load_boundary, validate_points


def stream_seed(seed: int, rank: int, worker: int, start_step: int) -> int:
    """A distinct, reproducible seed per (run seed, DDP rank, loader worker, resume step)."""
    return int(np.random.SeedSequence([seed, rank, worker, start_step]).generate_state(1)[0])


class AmbientSamples(IterableDataset):
    """An endless stream of batches {"x": (num_samples, dim)} drawn uniformly from [-1, 1]^dim.

    Each DDP rank and loader worker draws its own stream; ``start_step`` makes a resumed run continue
    with fresh samples instead of replaying the first ones.
    """

    def __init__(self, dim: int, num_samples: int, seed: int = 0, rank: int = 0, start_step: int = 0):
        self.dim, self.num_samples = dim, num_samples
        self.seed, self.rank, self.start_step = seed, rank, start_step

    def __iter__(self) -> Iterator[dict[str, torch.Tensor]]:
        info = get_worker_info()
        worker = info.id if info is not None else 0
        gen = torch.Generator().manual_seed(stream_seed(self.seed, self.rank, worker, self.start_step))
        while True:
            yield {"x": torch.rand(self.num_samples, self.dim, generator=gen) * 2.0 - 1.0}


class MinimalSurfaceDataModule(L.LightningDataModule):
    """Boundary Γ (validated at construction, so bad input stops before training) and ambient samples.

    3D: ``curve`` is a named curve (trefoil, hopf, borromean, circle) or a curve file.
    2D: ``points`` [[x, y], ...] with ``signs`` [±1, ...].
    """

    def __init__(
        self,
        dim: int = 3,
        curve: str = "trefoil",
        curve_vertices: int = 100,
        curve_scale: float = 1.0,
        points: Sequence[Sequence[float]] | None = None,
        signs: Sequence[float] | None = None,
        num_samples: int = 4096,
        num_workers: int = 0,
        seed: int = 0,
    ):
        super().__init__()
        if num_samples <= 0:
            raise ConfigError(f"data.num_samples={num_samples} must be a positive integer.")
        if curve_vertices < 3:
            raise ConfigError(f"data.curve_vertices={curve_vertices} must be at least 3.")
        if num_workers < 0:
            raise ConfigError(f"data.num_workers={num_workers} must be zero or positive.")
        self.dim, self.num_samples, self.num_workers, self.seed = dim, num_samples, num_workers, seed
        self.boundary: Boundary | PointBoundary
        if dim == 3:
            self.boundary = load_boundary(curve, n=curve_vertices, scale=curve_scale)
        elif dim == 2:
            if points is None or signs is None:
                raise ConfigError("data.points and data.signs are required for a 2D run (data.dim=2).")
            self.boundary = validate_points(points, signs)
        else:
            raise ConfigError(f"data.dim={dim} must be 2 or 3.")

    def train_dataloader(self) -> DataLoader:
        trainer = self.trainer
        rank = trainer.global_rank if trainer is not None else 0
        start = trainer.global_step if trainer is not None else 0
        dataset = AmbientSamples(self.dim, self.num_samples, self.seed, rank, start)
        return DataLoader(dataset, batch_size=None, num_workers=self.num_workers,
                          persistent_workers=self.num_workers > 0)
