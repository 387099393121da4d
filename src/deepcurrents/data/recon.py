"""The DataModule for single-surface reconstruction (paper §5.2): a target Σ (a mesh with boundary, an
oriented point cloud with Γ from a curve file, or a mesh of a human-part dataset), validated before
training, and an endless stream of batches made in the loader workers by :mod:`deepcurrents.data.targets`.

Also the 2D curve target of paper Fig. 3e/3f (the semicircle through a custom metric).
"""

from __future__ import annotations

import logging
from collections.abc import Iterator, Sequence
from pathlib import Path

import lightning as L
import numpy as np
import torch
import trimesh
from torch.utils.data import DataLoader, IterableDataset

from deepcurrents.data.ambient import step_generators, step_loader
from deepcurrents.data.human_parts import dataset_path
from deepcurrents.data.sampling import NEAR_SAMPLING_KINDS, NearTargetSampler
from deepcurrents.data.targets import MeshTarget, PointCloudTarget, closest_point_sample, mesh_boundary_loops
from deepcurrents.errors import ConfigError, UserInputError, number_at_least, positive_int, share
from deepcurrents.geometry import Boundary, load_boundary, validate_loops, validate_points
from deepcurrents.geometry.curves import box_normalisation
from deepcurrents.geometry.meshes import consistent_winding, drop_repeated_faces, read_mesh
from deepcurrents.geometry.polyline import project_to_segments

log = logging.getLogger(__name__)


class TargetError(UserInputError):
    """A target surface or point cloud that cannot be reconstructed; the message says why."""


# ------------------------------------------------------------------------------------------ reading targets


def first_nonfinite_row(rows: np.ndarray) -> int:
    """The index of the first row (point) of ``rows`` (N, d) that holds a NaN or an infinity, for a refusal."""
    return int(np.flatnonzero(~np.isfinite(rows).all(1))[0])


def read_target_mesh(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """A triangle mesh from a file trimesh reads, cleaned for reconstruction: repeated triangles dropped, largest
    connected component (with a warning when there are several), its winding made consistent, no unreferenced
    vertices; TargetError with one sentence if it is missing, unreadable, empty, closed, non-orientable or has
    non-manifold edges. → (vertices (V, 3), faces (F, 3))."""
    path = Path(path)
    mesh = read_mesh(path, "Mesh file", TargetError)
    verts = np.asarray(mesh.vertices, np.float64)
    faces = np.asarray(mesh.faces, np.int64)
    faces = drop_repeated_faces(faces, f"Mesh '{path}'")
    from deepcurrents.data.human_parts_builder import cut_part, largest_component

    _check_manifold(path, faces)
    keep = largest_component(faces)
    if len(keep) < len(faces):
        log.warning("Mesh '%s' has several connected components; using the largest (%d of %d faces).",
                    path, len(keep), len(faces))
    used, faces = cut_part(verts, faces, keep)
    verts = verts[used]
    faces = consistent_winding(verts, faces, f"Mesh '{path}'", TargetError)  # of the part kept only
    if not _check_manifold(path, faces):
        raise TargetError(f"Mesh '{path}' is closed (it has no boundary edges); DeepCurrents reconstructs "
                          "surfaces with boundary.")
    return verts, faces


def _check_manifold(path, faces: np.ndarray) -> bool:
    """TargetError for edges shared by more than two triangles; → whether the mesh has boundary edges."""
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), 1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    if (counts > 2).any():
        raise TargetError(f"Mesh '{path}' has {(counts > 2).sum()} non-manifold edges (shared by more than "
                          "two triangles); its boundary loops are not defined.")
    return bool((counts == 1).any())


def read_oriented_points(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """An oriented point cloud: ``.ply`` with vertex properties nx, ny, nz (or a mesh's vertex normals),
    or ``.xyz``/``.txt``/``.npy`` with rows ``x y z nx ny nz``. → (points (P, 3), unit normals (P, 3))."""
    path = Path(path)
    if not path.is_file():
        raise TargetError(f"Point cloud file '{path}' does not exist.")
    suffix = path.suffix.lower()
    try:
        if suffix == ".ply":
            cloud = trimesh.load(path, process=False)
            raw = cloud.metadata.get("_ply_raw", {}).get("vertex", {}).get("data")
            # trimesh keeps a binary file's vertices as a structured array, an ASCII file's as a dict of arrays
            names = () if raw is None else tuple(raw) if isinstance(raw, dict) else raw.dtype.names or ()
            if not all(k in names for k in ("nx", "ny", "nz")):
                raise TargetError(f"Point cloud '{path}' has no normals (vertex properties nx, ny, nz); "
                                  "DeepCurrents needs oriented points.")
            keys = ("x", "y", "z", "nx", "ny", "nz")
            data = np.stack([np.asarray(raw[k], np.float64).reshape(-1) for k in keys], 1)
        elif suffix in (".xyz", ".txt", ".npy"):
            data = np.load(path) if suffix == ".npy" else np.loadtxt(path, ndmin=2)
            data = np.asarray(data, np.float64)
            if data.ndim != 2 or data.shape[1] < 6:
                raise TargetError(f"Point cloud '{path}' has no normals: expected rows 'x y z nx ny nz', got "
                                  f"{data.shape[1] if data.ndim == 2 else 0} columns.")
        else:
            raise TargetError(f"Point cloud '{path}' has unsupported extension '{suffix}' (use .ply, .xyz, "
                              ".txt or .npy).")
    except TargetError:
        raise
    except Exception as err:
        raise TargetError(f"Point cloud '{path}' could not be read ({err}).") from err
    if len(data) < 10:
        raise TargetError(f"Point cloud '{path}' has {len(data)} points; it needs at least 10.")
    pts, nrm = data[:, :3], data[:, 3:6]
    if not np.isfinite(pts).all():
        raise TargetError(f"Point cloud '{path}' has NaN or infinite coordinates (first in point "
                          f"{first_nonfinite_row(pts)}).")
    norm = np.linalg.norm(nrm, axis=1)
    if not (np.isfinite(nrm).all() and (norm > 1e-12).all()):
        raise TargetError(f"Point cloud '{path}' has NaN, infinite or zero-length normals.")
    nrm = nrm / norm[:, None]
    opposed = opposed_neighbour_normals(pts, nrm)
    if opposed > OPPOSED_NORMALS_WARNING:
        log.warning("Point cloud '%s': %.0f %% of neighbouring points have normals pointing opposite ways (a "
                    "consistently oriented cloud has a few %%, at thin parts); the surface loss reads which side is "
                    "which from them, so orient them consistently first.", path, 100 * opposed)
    return pts, nrm


# Share of 8-nearest-neighbour pairs whose normals point opposite ways above which a cloud's normals are taken to be
# inconsistently oriented: consistent normals stay well below it even at a hand's fingers, a tenth flipped is above
# (docs/notes/code.md).
OPPOSED_NORMALS_WARNING = 0.1


def opposed_neighbour_normals(points: np.ndarray, normals: np.ndarray, k: int = 8, at_most: int = 20000) -> float:
    """The share of (point, one of its ``k`` nearest neighbours) pairs whose unit normals have a negative dot
    product, over a fixed subsample of ``at_most`` points. points, normals (P, 3) → a fraction in [0, 1]."""
    from scipy.spatial import cKDTree

    if len(points) > at_most:
        keep = np.random.default_rng(0).choice(len(points), at_most, replace=False)
        points, normals = points[keep], normals[keep]
    k = min(k, len(points) - 1)
    _, idx = cKDTree(points).query(points, k + 1)
    return float(((normals[:, None, :] * normals[idx[:, 1:]]).sum(-1) < 0).mean())


def normalisation(points: np.ndarray, mode: bool | str, half_extent: float = 0.5) -> tuple[float, np.ndarray]:
    """(scale, offset) with model coordinates = (input − offset) / scale.

    mode True: centre the bounding box and fit it in [-half_extent, half_extent]^3 (the paper's box);
    "auto": only when the input does not already fit in [-0.9, 0.9]^3; False: identity.
    (geometry.curves.box_normalisation, shared with minimal-surface curves.)
    """
    return box_normalisation(points, mode, half_extent, safe_extent=0.9, what="The target")


# ------------------------------------------------------------------------------------------ samples

class TargetSamples(IterableDataset):
    """Endless batches of :func:`deepcurrents.data.targets.target_sample` for one target; the target's
    trees are built inside each worker (libigl's AABB does not pickle)."""

    def __init__(self, target: dict, loops: list[np.ndarray], num_samples: int, num_surface_samples: int,
                 boundary_sigma: float, boundary_weighting: bool, surface_loss: bool, seed: int = 0,
                 rank: int = 0, start_step: int = 0, batch_kind: str = "current", near_sigma: float = 0.05,
                 ambient: dict | None = None):
        self.target, self.loops = target, loops
        self.ambient = dict(ambient or {"kind": "uniform"})  # see ambient_sampler
        self.batch_kind, self.near_sigma = batch_kind, near_sigma
        self.num_samples, self.num_surface_samples = num_samples, num_surface_samples
        self.kwargs = {"boundary_sigma": boundary_sigma, "boundary_weighting": boundary_weighting,
                       "surface_loss": surface_loss}
        self.seed, self.rank, self.start_step = seed, rank, start_step

    def build(self) -> MeshTarget | PointCloudTarget:
        if self.target["kind"] == "mesh":
            return MeshTarget(self.target["vertices"], self.target["faces"], self.loops)
        return PointCloudTarget(self.target["points"], self.target["normals"], self.loops)

    def __iter__(self) -> Iterator[dict[str, torch.Tensor]]:
        target = self.build()
        ambient = ambient_sampler(target, self.ambient, self.seed)
        for _, gen in step_generators(self.seed, self.rank, self.start_step):  # batch = f(seed, rank, step)
            if self.batch_kind == "closest_point":  # the baseline: x and its closest point on Σ
                yield closest_point_sample(target, self.num_samples, self.num_surface_samples, gen,
                                           self.near_sigma)
            else:
                yield target.sample(self.num_samples, self.num_surface_samples, gen, ambient=ambient,
                                    **self.kwargs)


AMBIENT_KEYS = ("kind", "uniform_fraction", "near_sigma", "anchors", "weighted")


def ambient_options(sampling: dict | None, key: str = "data.sampling", anchors: bool = True) -> dict:
    """``data.sampling`` of a reconstruction or a family, checked (one sentence naming the key). kind "uniform" (the
    paper's samples of [-1, 1]^3) or "near" (``NearTargetSampler``: ``uniform_fraction`` uniform, the rest
    Gaussian, σ = ``near_sigma``, around ``anchors`` fixed points of Σ; ``weighted``: importance weights).
    ``key`` names the node in messages; ``anchors=False``: a sampler whose anchors come from elsewhere (the
    interpolation regulariser's: the batch's surface samples), so the key is refused."""
    sampling = dict(sampling or {})
    allowed = AMBIENT_KEYS if anchors else tuple(k for k in AMBIENT_KEYS if k != "anchors")
    unknown = set(sampling) - set(allowed)
    if unknown:
        raise ConfigError(f"{key} has unknown keys {sorted(unknown)}; it takes {', '.join(allowed)}.")
    kind = sampling.setdefault("kind", "uniform")
    if kind not in NEAR_SAMPLING_KINDS:
        raise ConfigError(f"{key}.kind={kind!r} must be one of {', '.join(NEAR_SAMPLING_KINDS)} for a "
                          "reconstruction or a family.")
    if kind == "near":
        if anchors:
            positive_int(f"{key}.anchors", sampling.setdefault("anchors", 4096))
        number_at_least(f"{key}.near_sigma", sampling.setdefault("near_sigma", 0.02), strict=True)
        share(f"{key}.uniform_fraction", sampling.setdefault("uniform_fraction", 0.5))
        sampling["weighted"] = bool(sampling.get("weighted", True))
    return sampling


def ambient_sampler(target: MeshTarget | PointCloudTarget, sampling: dict,
                    seed: int = 0) -> NearTargetSampler | None:
    """The ambient sampler of ``ambient_options`` for a built target: None for uniform samples; the anchors
    of "near" are drawn once from Σ with ``seed`` (the same in every worker and on every resume)."""
    if sampling.get("kind", "uniform") == "uniform":
        return None
    anchors, _ = target.sample_surface(int(sampling["anchors"]), torch.Generator().manual_seed(seed))
    return NearTargetSampler(anchors, float(sampling["near_sigma"]), float(sampling["uniform_fraction"]),
                             weighted=bool(sampling["weighted"]))


class ReconstructionDataModule(L.LightningDataModule):
    """A reconstruction target and its training batches (paper §5.2: 4000 ambient + 4000 surface samples).

    The target is one of (checked in this order):
      - ``mesh``: a triangle mesh with boundary; Γ = its boundary loops oriented with its normals;
      - ``points`` with ``curve``: an oriented point cloud (.ply with normals, .xyz) and Γ from a curve file;
      - ``category`` (with ``source``, ``index``, ``root``): ``root/source/category/NNN.ply`` (``make data``).

    ``normalize``: True/"auto"/False, see :func:`normalisation` (dataset meshes are already in [-0.5, 0.5]^3).
    ``batch_kind``: "current" (DeepCurrents' batches) or "closest_point" (the baseline's: ``num_samples``
    uniform points and ``num_surface_samples`` points near Σ, σ = ``near_sigma``, with their closest points).
    ``sampling``: where DeepCurrents' ambient samples come from (``ambient_options``: the paper's uniform
    samples by default, or "near": concentrated near Σ with importance weights).
    """

    def __init__(
        self,
        mesh: str | None = None,
        points: str | None = None,
        curve: str | None = None,
        category: str | None = None,
        source: str = "anny",
        index: int = 0,
        root: str = "data",
        normalize: bool | str = "auto",
        num_samples: int = 4000,
        num_surface_samples: int = 4000,
        boundary_sigma: float = 0.1,
        boundary_weighting: bool = True,
        surface_loss: bool = True,
        curve_tolerance: float = 0.05,
        batch_kind: str = "current",
        near_sigma: float = 0.05,
        sampling: dict | None = None,
        num_workers: int = 0,
        seed: int = 0,
    ):
        super().__init__()
        for key, value in (("num_samples", num_samples), ("num_surface_samples", num_surface_samples)):
            positive_int(f"data.{key}", value)
        # boundary_sigma, curve_tolerance, num_workers, batch_kind, near_sigma, normalize: experiments.schema
        curve_tolerance = float(curve_tolerance)
        self.batch_kind, self.near_sigma = batch_kind, float(near_sigma)
        self.ambient = ambient_options(sampling)
        self.num_samples, self.num_surface_samples = num_samples, num_surface_samples
        self.sampling = {"boundary_sigma": float(boundary_sigma),
                         "boundary_weighting": bool(boundary_weighting), "surface_loss": bool(surface_loss)}
        self.num_workers, self.seed = num_workers, seed

        mesh, name = self._target_file(mesh, points, curve, category, source, index, root)
        self.source_file = str(mesh or points)
        if mesh is not None:
            loops = self._read_mesh(mesh, normalize)
        else:
            loops = self._read_points(points, curve, normalize, curve_tolerance)
        self.boundary = Boundary(loops, name)
        self.loops = loops

    @staticmethod
    def _target_file(mesh: str | None, points: str | None, curve: str | None, category: str | None, source: str,
                     index: int, root: str) -> tuple[str | None, str]:
        """(the target mesh's file, None for a point cloud; the run's name for the target): a dataset category
        resolved to its file, a warning for the inputs a mesh makes unused."""
        if (mesh is not None or points is None and category is not None) and (points or curve) is not None:
            ignored = " and ".join(k for k, v in (("data.points", points), ("data.curve", curve)) if v is not None)
            log.warning("%s is given, so %s %s ignored: Γ is the mesh's own boundary.",
                        "data.mesh" if mesh is not None else "data.category", ignored,
                        "are" if " and " in ignored else "is")
        if mesh is None and points is None:
            if category is None:
                raise ConfigError("Reconstruction needs a target: data.mesh=PATH, data.points=PATH with "
                                  "data.curve=PATH, or data.category=NAME (a dataset built by `make data`).")
            if isinstance(index, bool) or not isinstance(index, int):
                raise ConfigError(f"data.index={index!r} must be an integer.")
            mesh = str(dataset_path(root, source, category, index))
            return mesh, f"{source}/{category}/{Path(mesh).stem}"
        return mesh, Path(mesh or points).stem

    def _read_mesh(self, mesh: str, normalize: bool | str) -> list[np.ndarray]:
        """A target mesh, normalised (``self.target``, ``self.scale``, ``self.offset``) → Γ, its boundary loops."""
        verts, faces = read_target_mesh(mesh)
        self.scale, self.offset = normalisation(verts, normalize)
        verts = (verts - self.offset) / self.scale
        loops = validate_loops(mesh_boundary_loops(verts, faces), f"of mesh '{mesh}'")
        self.target = {"kind": "mesh", "vertices": verts, "faces": faces}
        return loops

    def _read_points(self, points: str, curve: str | None, normalize: bool | str,
                     curve_tolerance: float) -> list[np.ndarray]:
        """An oriented point cloud and its curve file, normalised together (``self.target``, ``self.scale``,
        ``self.offset``) → Γ, the curve's loops oriented with the cloud's normals."""
        if curve is None:
            raise ConfigError(f"data.points='{points}' needs data.curve=PATH: the boundary Γ of the "
                              "surface.")
        pts, nrm = read_oriented_points(points)
        self.scale, self.offset = normalisation(pts, normalize)
        pts = (pts - self.offset) / self.scale
        loops = [(lp - self.offset) / self.scale for lp in load_boundary(curve, domain=np.inf).loops]
        # with the cloud centred and scaled, a curve outside the domain is a curve off the cloud: say that first
        # (the domain sentence would ask for the normalisation already on); without it, the domain comes first
        if normalize is not False:
            self._check_curve_near_points(loops, pts, curve, points, curve_tolerance)
        loops = validate_loops(loops, f"'{curve}'")
        if normalize is False:
            self._check_curve_near_points(loops, pts, curve, points, curve_tolerance)
        loops = self._orient_curve_with_normals(loops, pts, nrm, curve, points)
        self.target = {"kind": "points", "points": pts, "normals": nrm}
        return loops

    @staticmethod
    def _check_curve_near_points(loops, pts, curve, points, tolerance: float) -> None:
        """Γ must lie on the cloud: each curve vertex within ``tolerance`` × the cloud's size of a point."""
        from scipy.spatial import cKDTree

        verts = np.concatenate(loops)
        dist, _ = cKDTree(pts).query(verts)
        size = float((pts.max(0) - pts.min(0)).max())
        if dist.max() > tolerance * size:
            raise TargetError(f"Curve '{curve}' does not lie near the points of '{points}': a curve vertex "
                              f"is {dist.max():.3g} from the nearest point (allowed {tolerance * size:.3g}: "
                              f"data.curve_tolerance={tolerance:g} of the cloud's size).")

    @staticmethod
    def _orient_curve_with_normals(loops: list[np.ndarray], pts: np.ndarray, normals: np.ndarray, curve,
                                   points) -> list[np.ndarray]:
        """Γ must run with the normals (the right-hand rule: Stokes' ∫_Σ n dA = ½ ∮_Γ x × dx). The integral is
        estimated with each point's share of the area, the square of the distance to its 8th neighbour (scans
        sample unevenly). Where the cloud has a clear net direction (that mean unit normal ≥ 0.2 long: a cap or
        a disk, not a tube or a nearly closed part) and Γ's vector area points against it (cosine < −0.5), every
        loop is reversed, with a warning: traced the other way, the run fits the surface's complement."""
        from scipy.spatial import cKDTree

        vector_area = sum(0.5 * np.cross(lp, np.roll(lp, -1, 0)).sum(0) for lp in loops)
        disks = sum(np.linalg.norm(np.roll(lp, -1, 0) - lp, axis=1).sum() ** 2 / (4 * np.pi) for lp in loops)
        k = min(8, len(pts) - 1)
        share = cKDTree(pts).query(pts, k=k + 1)[0][:, -1] ** 2 if k > 0 else np.ones(len(pts))
        mean_normal = (share[:, None] * normals).sum(0) / max(share.sum(), 1e-300)
        if np.linalg.norm(mean_normal) < 0.2 or np.linalg.norm(vector_area) < 0.1 * disks:
            return loops
        cosine = vector_area @ mean_normal / (np.linalg.norm(vector_area) * np.linalg.norm(mean_normal))
        if cosine >= -0.5:
            return loops
        log.warning("Curve '%s' runs against the normals of '%s' (by the right-hand rule its loops enclose the "
                    "other side: cosine %.2f between its vector area and the mean normal); reversed its loops.",
                    curve, points, cosine)
        return [lp[::-1].copy() for lp in loops]

    def model_kwargs(self) -> dict:
        """The target geometry (model coordinates) and the map back to the input's coordinates."""
        return {"target": {**self.target, "scale": self.scale, "offset": np.asarray(self.offset, np.float64),
                           "source": self.source_file}}

    def train_dataloader(self) -> DataLoader:
        trainer = self.trainer
        rank = trainer.global_rank if trainer is not None else 0
        start = trainer.global_step if trainer is not None else 0
        dataset = TargetSamples(self.target, self.loops, self.num_samples, self.num_surface_samples,
                                seed=self.seed, rank=rank, start_step=start, batch_kind=self.batch_kind,
                                near_sigma=self.near_sigma, ambient=self.ambient, **self.sampling)
        return step_loader(dataset, self.num_workers, rank)


# ------------------------------------------------------------------------------------------ 2D: Fig. 3e/3f

def curve_metric_2d(x: torch.Tensor, curve: torch.Tensor) -> torch.Tensor:
    """B_x = I − n nᵀ for an open 2D polyline target (n its unit normal at the closest point), and I where
    the closest point is an end point (Γ). x (N, 2), curve (K, 2) → (N, 2, 2)."""
    starts, ends = curve[:-1].to(x), curve[1:].to(x)
    proj = project_to_segments(x, starts, ends)
    tangent = (ends - starts)[proj.segment]
    tangent = tangent / tangent.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    normal = torch.stack([-tangent[:, 1], tangent[:, 0]], -1)
    at_end = ((proj.segment == 0) & (proj.t <= 0)) | ((proj.segment == len(starts) - 1) & (proj.t >= 1))
    normal = torch.where(at_end.unsqueeze(-1), torch.zeros_like(normal), normal)
    eye = torch.eye(2, dtype=x.dtype, device=x.device).expand(len(x), 2, 2)
    return eye - normal.unsqueeze(-1) * normal.unsqueeze(-2)


def semicircle(radius: float = 0.5, n: int = 200) -> np.ndarray:
    """The upper semicircle from (−r, 0) to (r, 0) through (0, r). → (n + 1, 2)."""
    t = np.linspace(np.pi, 0.0, n + 1)
    return radius * np.stack([np.cos(t), np.sin(t)], 1)


class CurveMetricSamples(IterableDataset):
    """Endless batches {"x": (N, 2), "metric": (N, 2, 2)} for a 2D curve target."""

    def __init__(self, curve: np.ndarray, num_samples: int, seed: int = 0, rank: int = 0,
                 start_step: int = 0):
        self.curve = torch.as_tensor(curve, dtype=torch.float32)
        self.num_samples, self.seed, self.rank, self.start_step = num_samples, seed, rank, start_step

    def __iter__(self):
        for _, gen in step_generators(self.seed, self.rank, self.start_step):  # batch = f(seed, rank, step)
            x = torch.rand(self.num_samples, 2, generator=gen) * 2.0 - 1.0
            yield {"x": x, "metric": curve_metric_2d(x, self.curve)}


class CurveMetricDataModule(L.LightningDataModule):
    """Paper Fig. 3d–f: a 2D curve reconstructed by mass minimisation under B = I − n nᵀ. Γ = the curve's
    end points (−1 where it starts, +1 where it ends); the model is the usual 2D ``CurrentModule``.

    ``curve``: "semicircle" (radius ``radius``) or a list of [x, y] vertices of an open polyline.
    """

    def __init__(self, curve: str | Sequence[Sequence[float]] = "semicircle", radius: float = 0.5,
                 num_samples: int = 4096, num_workers: int = 0, seed: int = 0):
        super().__init__()
        if isinstance(curve, str):
            if curve != "semicircle":
                raise ConfigError(f"data.curve='{curve}' must be 'semicircle' or a list of [x, y] points.")
            if not number_at_least("data.radius", radius, strict=True) < 1:
                raise ConfigError(f"data.radius={radius} must be in (0, 1) to fit in [-1, 1]^2.")
            pts = semicircle(radius)
        else:
            try:
                pts = np.asarray(curve, np.float64)
            except (TypeError, ValueError):
                pts = np.zeros((0,))
            if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 2:
                raise ConfigError("data.curve must be 'semicircle' or an open polyline of at least two [x, y] points "
                                  "(numbers), e.g. data.curve=[[-0.5,0],[0,0.5],[0.5,0]].")
            if not np.isfinite(pts).all():
                raise ConfigError(f"data.curve has NaN or infinite coordinates (first in point "
                                  f"{first_nonfinite_row(pts)}).")
            if np.abs(pts).max() >= 1:
                raise ConfigError("data.curve must lie inside the domain (-1, 1)^2, where the samples are drawn.")
            if np.linalg.norm(pts[0] - pts[-1]) < 1e-9:
                raise ConfigError("data.curve is closed (its first and last points coincide): a closed curve has no "
                                  "boundary to reconstruct from; give an open polyline.")
        self.curve, self.num_samples, self.num_workers, self.seed = pts, num_samples, num_workers, seed
        self.boundary = validate_points(pts[[0, -1]], [-1.0, 1.0], source="of data.curve (its end points)")

    def metric_fn(self, x: torch.Tensor) -> torch.Tensor:
        """B_x of this target at any points, for pictures (Fig. 3d's ellipses). x (N, 2) → (N, 2, 2)."""
        return curve_metric_2d(x, torch.as_tensor(self.curve, dtype=x.dtype, device=x.device))

    def train_dataloader(self) -> DataLoader:
        trainer = self.trainer
        rank = trainer.global_rank if trainer is not None else 0
        start = trainer.global_step if trainer is not None else 0
        dataset = CurveMetricSamples(self.curve, self.num_samples, self.seed, rank, start)
        return step_loader(dataset, self.num_workers, rank)
