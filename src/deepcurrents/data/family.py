"""A family of meshes with boundary (one category, e.g. hands) and its DataModule for the autodecoder
(paper §4.3, §5.3).

Every mesh of a family must have the same number B of boundary loops. Loops are matched across meshes
against the first mesh (the reference) — see ``geometry.correspondence``:

- loop b of every mesh is the loop whose centroid is assigned to the reference's loop b by the Hungarian
  method on centroid distances (meshes of a category are rigidly aligned, so centroids identify loops);
- each loop keeps the orientation its mesh's faces give it (Stokes; ``data.targets.mesh_boundary_loops``);
- each loop's vertices are cyclically shifted to start where the reference's starts (least squares over
  all shifts for equal vertex counts, nearest vertex otherwise).

So encoder b always sees "the same" loop, and two shapes' loops can be interpolated vertex by vertex.

Every step, each DDP rank draws ``meshes_per_batch`` meshes from its own shard of the family (mesh i
belongs to rank i mod world_size), augments each (``data.augment``) and samples it as in reconstruction
(``data.targets.target_sample``), all in DataLoader workers on the CPU, each with its own stream.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import lightning as L
import numpy as np
import torch
import trimesh
from scipy.spatial import cKDTree
from torch.utils.data import DataLoader, IterableDataset

from deepcurrents.data.ambient import step_generators, step_loader
from deepcurrents.data.augment import AugmentationRanges, augment_mesh
from deepcurrents.data.recon import ambient_options, ambient_sampler
from deepcurrents.data.sampling import NearTargetSampler
from deepcurrents.data.targets import (
    SURFACE_EPSILON,
    MeshTarget,
    mesh_boundary_loops,
    surface_epsilon_range,
    target_sample,
)
from deepcurrents.errors import ConfigError, UserInputError, number_at_least, positive_int
from deepcurrents.geometry.correspondence import best_cyclic_shift, match_loops, orientation_agrees
from deepcurrents.geometry.harmonic import HarmonicSkinning
from deepcurrents.geometry.meshes import consistent_winding, drop_repeated_faces, read_mesh
from deepcurrents.geometry.topology import border_edges

log = logging.getLogger(__name__)

MESH_SUFFIXES = (".ply", ".obj", ".off", ".stl")


class FamilyError(UserInputError):
    """A family dataset that cannot be used (files, loop counts, sizes); the message says why."""


@dataclass
class FamilyMesh:
    """One training mesh: vertices (V, 3) float64, faces (F, 3) int64, its B boundary loops as vertex
    index arrays (matched and aligned across the family), and its harmonic skinning."""

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    loops: list[np.ndarray]
    skinning: HarmonicSkinning

    def loop_points(self, vertices: np.ndarray | None = None) -> list[np.ndarray]:
        """Γ as B arrays (M_b, 3) of the given (e.g. augmented) vertices, default the mesh's own."""
        v = self.vertices if vertices is None else vertices
        return [v[idx] for idx in self.loops]

    def trimesh(self) -> trimesh.Trimesh:
        return trimesh.Trimesh(self.vertices, self.faces, process=False)


def family_files(path: str | Path | Sequence[str], max_meshes: int | None = None) -> list[Path]:
    """The mesh files of a family: a directory's .ply/.obj/.off files in name order, or a list of files."""
    if isinstance(path, (str, Path)):
        root = Path(path)
        if not root.exists():
            raise FamilyError(
                f"data.path='{root}' does not exist (build the human-part datasets with `make data`, "
                "or point data.path at a folder of meshes)."
            )
        if root.is_dir():
            files = sorted(p for p in root.iterdir() if p.suffix.lower() in MESH_SUFFIXES)
            if not files:
                raise FamilyError(f"data.path='{root}' contains no .ply, .obj, .off or .stl meshes.")
        else:
            files = [root]
    else:
        files = [Path(p) for p in path]
        if not files:
            raise FamilyError("data.path=[] lists no meshes; give a folder of meshes or a list of mesh files.")
        for p in files:
            if not p.is_file():
                raise FamilyError(f"Family mesh '{p}' does not exist or is not a file.")
    if max_meshes is not None:
        if int(max_meshes) < 1:
            raise ConfigError(f"data.max_meshes={max_meshes} must be a positive integer (or null for all).")
        files = files[: int(max_meshes)]
    return files


def split_held_out(files: Sequence[Path], max_meshes: int | None, held_out: int) -> tuple[list[Path], list[Path]]:
    """(training files, held-out files): the last ``held_out`` files are kept out of training, the first
    ``max_meshes`` of the others (all when None) are trained. ConfigError when nothing is left to train."""
    if isinstance(held_out, bool) or not isinstance(held_out, (int, np.integer)) or held_out < 0:
        raise ConfigError(f"data.held_out={held_out!r} must be zero or a positive integer.")
    if held_out >= len(files):
        raise ConfigError(f"data.held_out={held_out} leaves no mesh to train on: the family has {len(files)}.")
    train, kept_out = list(files[: len(files) - held_out]), list(files[len(files) - held_out:])
    if max_meshes is not None:
        if int(max_meshes) < 1:
            raise ConfigError(f"data.max_meshes={max_meshes} must be a positive integer (or null for all).")
        train = train[: int(max_meshes)]
    return train, kept_out


def read_family_mesh(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) float64 and faces (F, 3) int64 of a triangle mesh file, vertices in the file's order, the
    faces cleaned as every target's (``geometry.meshes``: repeats dropped, winding made consistent)."""
    mesh = read_mesh(path, "Family mesh", FamilyError)
    name = f"Family mesh '{path}'"
    faces = consistent_winding(np.asarray(mesh.vertices, dtype=np.float64),
                               drop_repeated_faces(np.asarray(mesh.faces, dtype=np.int64), name), name, FamilyError)
    mesh = trimesh.Trimesh(mesh.vertices, faces, process=False)
    mesh.remove_unreferenced_vertices()  # keeps the order of the others; stray vertices cannot be skinned
    return np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64)


def loop_indices(vertices: np.ndarray, faces: np.ndarray) -> list[np.ndarray]:
    """Γ of a mesh as vertex index arrays, in the orientation of ``mesh_boundary_loops`` (whose loops are
    coordinates: we find each loop vertex among the mesh's boundary vertices)."""
    loops = mesh_boundary_loops(vertices, faces)
    if not loops:
        return []
    candidates = np.unique(border_edges(faces))
    dist, nearest = cKDTree(vertices[candidates]).query(np.concatenate(loops))
    assert dist.max() == 0.0, "boundary loop vertices are mesh vertices"
    idx = candidates[nearest]
    return np.split(idx, np.cumsum([len(lp) for lp in loops])[:-1])


def load_family(files: Sequence[Path], bound: float = 0.98) -> list[FamilyMesh]:
    """Reads, checks and matches the meshes of a family (see the module docstring). Raises FamilyError."""
    meshes: list[FamilyMesh] = []
    for path in files:
        v, f = read_family_mesh(path)
        loops = loop_indices(v, f)
        if not loops:
            raise FamilyError(f"Family mesh '{path}' is closed: it has no boundary loop.")
        if meshes and len(loops) != len(meshes[0].loops):
            raise FamilyError(
                f"Family mesh '{path.name}' has {len(loops)} boundary loops but '{meshes[0].name}' has "
                f"{len(meshes[0].loops)}; every mesh of a family must have the same number of loops."
            )
        if np.abs(v).max() >= bound:
            raise FamilyError(
                f"Family mesh '{path}' reaches |coordinate| = {np.abs(v).max():.3g}, outside "
                f"[-{bound:g}, {bound:g}]^3; scale the family into [-0.5, 0.5]^3 as the paper does."
            )
        if meshes:
            ref = meshes[0].loop_points()
            pts = [v[idx] for idx in loops]
            loops = [loops[j] for j in match_loops(pts, ref)]
            aligned = []
            for b, idx in enumerate(loops):
                if not orientation_agrees(v[idx], ref[b]):
                    log.warning("Family mesh '%s': loop %d turns against the reference's loop %d (its faces "
                                "are oriented the other way).", path.name, b, b)
                aligned.append(np.roll(idx, -best_cyclic_shift(v[idx], ref[b])))
            loops = aligned
        skinning = HarmonicSkinning(v, f, np.concatenate(loops), name=str(path))
        meshes.append(FamilyMesh(path.name, v, f, loops, skinning))
    return meshes


def collate_shapes(items: list[dict]) -> dict[str, torch.Tensor]:
    """Stacks per-mesh samples into a batch of S shapes. Each item: "index", "loops" (B arrays (M_b, 3)),
    and the tensors of ``reconstruction_sample``. → "x" (S, N, 3), "metric" (S, N, 3, 3),
    "surface_points" / "surface_normals" (S, M, 3), "epsilon" (S, M), "index" (S,),
    "loops" (S, B, L, 3) zero-padded, "loop_mask" (S, B, L)."""
    batch = {k: torch.stack([it[k] for it in items]) for k in items[0] if k not in ("loops", "index")}
    batch["index"] = torch.tensor([it["index"] for it in items], dtype=torch.long)
    s, b = len(items), len(items[0]["loops"])
    length = max(len(lp) for it in items for lp in it["loops"])
    loops = torch.zeros(s, b, length, 3)
    mask = torch.zeros(s, b, length, dtype=torch.bool)
    for i, it in enumerate(items):
        for j, lp in enumerate(it["loops"]):
            loops[i, j, : len(lp)] = torch.as_tensor(lp, dtype=torch.float32)
            mask[i, j, : len(lp)] = True
    batch["loops"], batch["loop_mask"] = loops, mask
    return batch


class FamilySamples(IterableDataset):
    """An endless stream of family batches (``collate_shapes``) for one DDP rank.

    Args:
        meshes: the whole family (indices are latent-code rows).
        shard: the mesh indices this rank trains.
        meshes_per_batch: shapes per batch (without replacement when the shard is large enough).
        num_samples, num_surface_samples: ambient and surface samples per mesh.
        augment: random augmentation per mesh and step (paper) or the meshes as they are.
    """

    def __init__(self, meshes: list[FamilyMesh], shard: Sequence[int], meshes_per_batch: int, num_samples: int,
                 num_surface_samples: int, ranges: AugmentationRanges, augment: bool = True,
                 boundary_sigma: float = 0.1, boundary_weighting: bool = True, seed: int = 0, rank: int = 0,
                 start_step: int = 0, metric_band: float | None = None, sampling: dict | None = None,
                 surface_epsilon: float | tuple[float, float] = SURFACE_EPSILON):
        self.meshes, self.shard = meshes, np.asarray(shard, dtype=np.int64)
        self.meshes_per_batch, self.num_samples = meshes_per_batch, num_samples
        self.num_surface_samples, self.ranges, self.augment = num_surface_samples, ranges, augment
        self.boundary_sigma, self.boundary_weighting = boundary_sigma, boundary_weighting
        self.seed, self.rank, self.start_step = seed, rank, start_step
        self.metric_band, self.sampling = metric_band, ambient_options(sampling)
        self.surface_epsilon = surface_epsilon
        self.targets: dict[int, tuple] = {}  # unaugmented meshes' (target, ambient sampler), built in each worker

    def unaugmented(self, index: int) -> tuple[MeshTarget, NearTargetSampler | None]:
        """Mesh ``index`` as stored: its target (AABB tree, border) and ambient sampler, built once per worker."""
        if index not in self.targets:
            mesh = self.meshes[index]
            target = MeshTarget(mesh.vertices, mesh.faces, mesh.loop_points())
            self.targets[index] = (target, ambient_sampler(target, self.sampling, seed=index))
        return self.targets[index]

    def sample_mesh(self, index: int, generator: torch.Generator) -> dict:
        """One mesh, augmented and sampled."""
        mesh = self.meshes[index]
        kwargs = {"boundary_sigma": self.boundary_sigma, "boundary_weighting": self.boundary_weighting,
                  "surface_loss": True, "metric_band": self.metric_band, "surface_epsilon": self.surface_epsilon}
        if self.augment:  # a new mesh every step: its AABB tree (and near sampler) is built and dropped
            v = augment_mesh(mesh.skinning, mesh.loops, generator, self.ranges)[0]
            loops = mesh.loop_points(v)
            target = self.unaugmented(index)[0].moved(v, loops)  # the faces' border reused (MeshTarget.moved)
            ambient = ambient_sampler(target, self.sampling, seed=index)
        else:  # the same mesh every step: its tree is built once
            loops = mesh.loop_points()
            target, ambient = self.unaugmented(index)
        item = target_sample(target, self.num_samples, self.num_surface_samples, generator, ambient=ambient,
                             **kwargs)
        item["index"], item["loops"] = index, loops
        return item

    def __iter__(self) -> Iterator[dict[str, torch.Tensor]]:
        n, k = len(self.shard), self.meshes_per_batch
        for _, gen in step_generators(self.seed, self.rank, self.start_step):  # batch = f(seed, rank, step)
            pick = torch.randperm(n, generator=gen)[:k] if n >= k else torch.randint(n, (k,), generator=gen)
            yield collate_shapes([self.sample_mesh(int(self.shard[i]), gen) for i in pick.tolist()])


class FamilyDataModule(L.LightningDataModule):
    """A family of meshes (checked and matched at construction, so bad input stops before training) and
    its stream of augmented batches.

    Args:
        path: a folder of meshes (``data/<source>/<category>``) or a list of mesh files.
        max_meshes: train only the first ``max_meshes`` files (None: all).
        held_out: the last ``held_out`` files are not trained: the final evaluation fits their latent codes
            alone (decoder and encoders frozen) and reports their UCD beside the training shapes'.
        meshes_per_batch: shapes per step and rank (paper: 8).
        num_samples: ambient samples per mesh (paper: 4000); num_surface_samples: surface samples per mesh.
        augment, rotation_deg, scale_range, shift, bound: the augmentation (``data.augment``).
        mesh_scale_range: [low, high] of a log-uniform scale of the whole mesh about the origin (beyond the
            paper; [1, 1], the default, is off; ``data.augment.AugmentationRanges``).
        boundary_sigma, boundary_weighting: the metric's boundary weighting (as reconstruction).
        num_workers: DataLoader worker processes (augmentation and sampling run there).
        metric_band: beyond the paper (None: off): samples farther than this from the (augmented) mesh get the
            Euclidean metric w I (``data.targets.target_sample``).
        sampling: the ambient samples, a reconstruction's ``data.sampling`` (``data.recon.ambient_options``):
            uniform (the paper's) or "near", importance-weighted around points of each (augmented) mesh.
        surface_epsilon: ε of the surface loss's offsets y ± εn (the paper's 0.02, sized for a part that fills
            the box; ``make data`` hands span a quarter to two fifths of it), or a range [ε_min, ε_max]: per
            sample the largest ε in it whose offsets stay clear of the rest of the mesh (beyond the paper;
            ``data.targets.clear_surface_epsilon``).
    """

    def __init__(
        self,
        path: str | Sequence[str],
        max_meshes: int | None = None,
        held_out: int = 0,
        meshes_per_batch: int = 8,
        num_samples: int = 4000,
        num_surface_samples: int = 4000,
        augment: bool = True,
        rotation_deg: float = 10.0,
        scale_range: Sequence[float] = (0.85, 1.15),
        shift: float = 0.05,
        bound: float = 0.98,
        boundary_sigma: float = 0.1,
        boundary_weighting: bool = True,
        num_workers: int = 0,
        seed: int = 0,
        mesh_scale_range: Sequence[float] = (1.0, 1.0),
        metric_band: float | None = None,
        sampling: dict | None = None,
        surface_epsilon: float | Sequence[float] = SURFACE_EPSILON,
    ):
        super().__init__()
        for key, value in (("meshes_per_batch", meshes_per_batch), ("num_samples", num_samples),
                           ("num_surface_samples", num_surface_samples)):
            positive_int(f"data.{key}", value)
        for key, value in (("scale_range", scale_range), ("mesh_scale_range", mesh_scale_range)):
            if len(value) != 2:
                raise ConfigError(f"data.{key}={list(value)} must be [low, high].")
        if metric_band is not None and (isinstance(metric_band, bool) or not isinstance(metric_band, (int, float))
                                        or not metric_band > 0):
            raise ConfigError(f"data.metric_band={metric_band!r} must be a positive distance (null: the paper's "
                              "metric).")
        # numbers first (a word would be a raw ValueError from float()); the ranges are checked by AugmentationRanges
        scales = {key: tuple(number_at_least(f"data.{key}", v, strict=True) for v in value)
                  for key, value in (("scale_range", scale_range), ("mesh_scale_range", mesh_scale_range))}
        # rotation_deg, shift, bound, num_workers, boundary_sigma: experiments.schema
        self.ranges = AugmentationRanges(float(rotation_deg), scales["scale_range"], float(shift), float(bound),
                                         scales["mesh_scale_range"])
        train, kept_out = split_held_out(family_files(path), max_meshes, held_out)
        # loaded together: held-out loops are matched to the same reference (the first training mesh)
        loaded = load_family(train + kept_out, bound=self.ranges.bound)
        self.meshes, self.held_out_meshes = loaded[: len(train)], loaded[len(train):]
        self.meshes_per_batch, self.num_samples = meshes_per_batch, num_samples
        self.num_surface_samples, self.augment = num_surface_samples, augment
        self.boundary_sigma, self.boundary_weighting = boundary_sigma, boundary_weighting
        self.num_workers, self.seed = num_workers, seed
        self.metric_band = metric_band
        self.sampling = ambient_options(sampling)
        low, high = surface_epsilon_range(surface_epsilon)
        self.surface_epsilon = high if low == high else (low, high)

    @property
    def num_loops(self) -> int:
        return len(self.meshes[0].loops)

    def model_kwargs(self) -> dict:
        """What the autodecoder needs to know of its data: sizes, names, the unaugmented boundaries."""
        return {
            "num_shapes": len(self.meshes),
            "num_loops": self.num_loops,
            "shape_names": [m.name for m in self.meshes],
            "train_loops": [m.loop_points() for m in self.meshes],
            "train_bounds": [np.stack([m.vertices.min(0), m.vertices.max(0)]) for m in self.meshes],
        }

    def shard(self, rank: int, world_size: int) -> np.ndarray:
        """The mesh indices trained by one DDP rank: i ≡ rank (mod world_size)."""
        if world_size > len(self.meshes):
            raise FamilyError(
                f"The family has {len(self.meshes)} meshes but training uses {world_size} processes; each "
                "process needs at least one mesh (use fewer devices or more meshes)."
            )
        return np.arange(rank, len(self.meshes), world_size)

    def train_dataloader(self) -> DataLoader:
        trainer = self.trainer
        rank = trainer.global_rank if trainer is not None else 0
        world = trainer.world_size if trainer is not None else 1
        start = trainer.global_step if trainer is not None else 0
        dataset = FamilySamples(
            self.meshes, self.shard(rank, world), self.meshes_per_batch, self.num_samples,
            self.num_surface_samples, self.ranges, self.augment, self.boundary_sigma, self.boundary_weighting,
            self.seed, rank, start, self.metric_band, self.sampling, self.surface_epsilon,
        )
        return step_loader(dataset, self.num_workers, rank)
