"""What the Python API hands back: a trained current to ask for f, ω, a mesh, a picture and numbers
(`Result`), and a family of them (`FamilyResult`).

Points, meshes, boundaries and areas are in the coordinates of the input the run was given (the units of your
curve or mesh): a run that moved its input into the box U = [-1, 1]³ (``data.normalize``) maps them back, as its
``mesh.ply`` and ``metrics.json`` do. ``units="model"`` asks in the box's coordinates instead.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch
import trimesh

from deepcurrents.api.inputs import curve_loops
from deepcurrents.errors import ConfigError, UserInputError, positive_int
from deepcurrents.eval.device import device_of
from deepcurrents.eval.meshing import extract_curve_2d, extract_surface
from deepcurrents.eval.meshing.polish import PolishResult, PolishSettings, polish_minimal_surface, polish_settings
from deepcurrents.eval.metrics import mass_estimate, mass_estimate_settings, mass_to_area
from deepcurrents.eval.plots import figure_pixels
from deepcurrents.eval.render import (
    DensitySettings,
    fit_camera,
    proposal_grid,
    render_current,
    render_current_2d,
    render_mesh,
    save_image,
)
from deepcurrents.geometry.correspondence import align_loops, interpolate_loops
from deepcurrents.geometry.meshes import write_mesh
from deepcurrents.models.current_module import input_mesh
from deepcurrents.models.loading import file_frame, mesh_settings, run_evaluation

Units = Literal["input", "model"]
MESH_SUFFIXES = (".ply", ".obj", ".off", ".stl", ".glb")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")


def as_points(x: Any, dim: int, name: str = "x") -> np.ndarray:
    """``x`` as float64 points (N, dim) (one point (dim,) becomes (1, dim)), or UserInputError naming ``name``."""
    try:
        points = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError):
        raise UserInputError(f"{name} must be an (N, {dim}) array of numbers; got {type(x).__name__}.") from None
    if points.ndim == 1 and points.shape[0] == dim:
        points = points[None]
    if points.ndim != 2 or points.shape[1] != dim:
        raise UserInputError(f"{name} has shape {tuple(points.shape)}; give points as an (N, {dim}) array.")
    if not np.isfinite(points).all():
        raise UserInputError(f"{name} holds NaN or infinite coordinates.")
    return points


class Result:
    """One trained current: a minimal surface, a reconstruction, a grid current, or one member of a family.

    Attributes:
        module: the LightningModule (``models.CurrentModule``, ``ReconstructionModule``, …), in eval mode.
        current: the current itself (``nn.NeuralCurrent``-like: ``evaluate(x) -> (f, ω)``, ``loops``), or None
            for the closest-point baseline, which is no current.
        name: what it is a surface of (the curve, the target, the family member).
        metrics: the run's final metrics (its ``metrics.json``; {} where none was written).
        checkpoint: the checkpoint file it was read from (None for a family member, which has none of its own).
        run_dir: the run's folder (None when unknown).
    """

    def __init__(self, module: torch.nn.Module, current: torch.nn.Module | None, *, name: str,
                 checkpoint: Path | None = None, run_dir: Path | None = None, metrics: dict[str, Any] | None = None,
                 frame: tuple[float, np.ndarray] | None = None,
                 mesher: Callable[[int | None], Any] | None = None):
        self.module, self.current, self.name = module, current, name
        self.checkpoint, self.run_dir = checkpoint, run_dir
        self.metrics: dict[str, Any] = dict(metrics or {})
        self._frame = frame  # input = model · scale + offset
        self._mesher = mesher  # resolution → extract_surface's result; None: the run's own meshing settings
        self._said: set = set()  # the coarse-grid warnings this result's meshings have already given
        self._meshings: dict[int | None, Any] = {}  # by resolution: meshing is the slow part of looking at it

    def __repr__(self) -> str:
        where = f", checkpoint='{self.checkpoint}'" if self.checkpoint else ""
        return f"{type(self).__name__}({self.name!r}, {type(self.module).__name__}{where})"

    # ---------------------------------------------------------------------------------------------- frame
    @property
    def dim(self) -> int:
        """2 or 3: the dimension of the ambient space."""
        return int(getattr(self._need_current("dim"), "dim", 3))

    @property
    def scale(self) -> float:
        """Input units per model unit (1 where the run did not move its input)."""
        return 1.0 if self._frame is None else float(self._frame[0])

    def _to_model(self, x: np.ndarray, units: Units) -> np.ndarray:
        self._check_units(units)
        if units == "model" or self._frame is None:
            return x
        return (x - self._frame[1][: x.shape[1]]) / self._frame[0]

    def _to_input(self, x: np.ndarray, units: Units) -> np.ndarray:
        if units == "model" or self._frame is None:
            return x
        return x * self._frame[0] + self._frame[1][: x.shape[1]]

    @staticmethod
    def _check_units(units: str) -> None:
        if units not in ("input", "model"):
            raise ConfigError(f"units={units!r} must be 'input' (the coordinates of the run's input) or 'model'.")

    def _need_current(self, what: str) -> torch.nn.Module:
        if self.current is None:
            raise UserInputError(f"{what} needs a current, but {self.name} is {type(self.module).__name__}, which "
                                 "has none (the closest-point baseline maps points to the surface instead).")
        return self.current

    # -------------------------------------------------------------------------------------------- fields
    @property
    def boundary(self) -> list[np.ndarray]:
        """Γ: the boundary loops, each (M_i, 3), in the input's coordinates (2D: the points (P, 2))."""
        current = self._need_current("boundary")
        if getattr(current, "dim", 3) == 2:
            return [self._to_input(current.poles.detach().cpu().double().numpy(), "input")]
        spec = (getattr(self.module, "hparams", None) or {}).get("boundary") or {}
        if self._mesher is None and spec.get("loops") is not None:  # float64, as the run read them
            return [self._to_input(np.asarray(lp, np.float64), "input") for lp in spec["loops"]]
        return [self._to_input(lp.detach().cpu().double().numpy(), "input") for lp in current.loops]

    def _evaluate(self, x: Any, units: Units, omega: bool, chunk_size: int):
        current = self._need_current("f and ω")
        points = self._to_model(as_points(x, self.dim), units)
        with torch.no_grad():
            return current.evaluate(torch.as_tensor(points, dtype=torch.float32, device=device_of(current)),
                                    chunk_size=chunk_size, omega=omega)

    def f(self, x: Any, *, units: Units = "input", chunk_size: int = 1 << 15) -> np.ndarray:
        """The scalar field f_θ at points x: (N, d) → (N,). Its jump across the surface is the current's
        normalisation (``alpha_scale``); the meshes are its level sets, or its phase's."""
        return self._evaluate(x, units, False, chunk_size).cpu().double().numpy()

    def omega(self, x: Any, *, units: Units = "input", chunk_size: int = 1 << 15) -> np.ndarray:
        """The current ω = ∇f_θ + α_Γ at points x: (N, d) → (N, d). In input units it is the model's ω divided by
        `scale` (a 1-form), so that ∫|ω| dx keeps its meaning as an area."""
        _, w = self._evaluate(x, units, True, chunk_size)
        w = w.cpu().double().numpy()
        return w if units == "model" else w / self.scale

    # -------------------------------------------------------------------------------------------- meshes
    def _surface(self, resolution: int | None):
        current = self._need_current("mesh()")
        if current.dim != 3:
            raise UserInputError(f"{self.name} is a 2D current, whose surface is a curve: use curves() instead "
                                 "of mesh().")
        if resolution is not None:
            positive_int("resolution", resolution, 8)
        if resolution not in self._meshings:
            self._meshings[resolution] = self._mesher(resolution) if self._mesher is not None else \
                extract_surface(current, **mesh_settings(self.module, resolution=resolution), said=self._said)
        return self._meshings[resolution]

    def mesh(self, resolution: int | None = None, *, units: Units = "input") -> trimesh.Trimesh:
        """The surface as a triangle mesh, its border on Γ, by the run's own meshing settings
        (``evaluation.mesh``); ``resolution``: cells along the longest side of the meshed region (default the
        run's). In the input's coordinates, as the run's ``mesh.ply``."""
        self._check_units(units)
        mesh = self._surface(resolution).mesh
        return input_mesh(mesh, self._frame) if units == "input" and self._frame is not None else mesh.copy()

    def polished(self, resolution: int | None = None, **settings: Any) -> PolishResult:
        """The minimal surface's mesh finished by the area flow with its border on Γ (``eval.meshing.polish``), in
        the input's coordinates: ``.mesh`` (the finest level), ``.areas`` per level, ``.extrapolated`` ± its
        ``.extrapolated_error`` (Γ's polyline), ``.curve_extrapolated`` ± its error (the smooth curve Γ samples),
        ``.topology``; ``.stopped`` says why not where it could not. ``settings``: ``PolishSettings``' fields
        (default the run's ``evaluation.mesh.polish``, e.g. ``levels=2``)."""
        if not getattr(self.module, "polishes_mesh", False) or self._mesher is not None:
            raise UserInputError(f"{self.name} is not a minimal surface: only those are polished.")
        fields = set(PolishSettings.__dataclass_fields__) - {"enabled"}
        unknown = sorted(set(settings) - fields)
        if unknown:
            raise UserInputError(f"polished() got {', '.join(unknown)}: its settings are {', '.join(sorted(fields))}.")
        # asked for, so polished even where the run's own polish was off
        options = polish_settings(run_evaluation(self.module).get("mesh"), **settings, enabled=True)
        return polish_minimal_surface(self.mesh(resolution), self.boundary, options)

    def curves(self, resolution: int | None = None, *, units: Units = "input") -> list[np.ndarray]:
        """A 2D current's curve: its polylines, each (K, 2)."""
        current = self._need_current("curves()")
        if current.dim != 2:
            raise UserInputError(f"{self.name} is a 3D current: use mesh() for its surface.")
        settings = dict(run_evaluation(self.module).get("curve") or {})
        if resolution is not None:
            settings["resolution"] = positive_int("resolution", resolution, 8)
        self._check_units(units)
        return [self._to_input(np.asarray(c, np.float64), units) for c in extract_curve_2d(current, **settings)]

    def mass_bound(self, samples: int | None = None, *, seed: int | None = None, units: Units = "input") -> float:
        """The extraction-free mass of the current, E_U|ω| in area units (length in 2D): an upper bound of the
        area of the minimal surface spanning Γ (paper §3), needing no mesh. Monte Carlo, stopped at the run's
        ``evaluation.mass_rel_stderr``; ``samples`` caps the samples (default the run's ``evaluation.mass_samples``)."""
        current = self._need_current("mass_bound()")
        self._check_units(units)
        evaluation = run_evaluation(self.module)
        settings = mass_estimate_settings(evaluation)
        if samples is not None:
            settings["num_samples"] = positive_int("samples", samples, 1024)
            settings["min_samples"] = min(settings.get("min_samples", 1 << 16), settings["num_samples"])
        mass, _ = mass_estimate(current, seed=int(seed if seed is not None else evaluation.get("seed", 12345)),
                                **settings)
        area = mass_to_area(mass, current.dim, current.alpha_scale)
        return area if units == "model" else area * self.scale ** (current.dim - 1)  # an area (3D), a length (2D)

    # ------------------------------------------------------------------------------------------ pictures
    def render(self, size: int = 256, *, mesh: bool = False, azimuth: float = 35.0, elevation: float = 25.0,
               samples: int = 48, background: Sequence[float] = (1.0, 1.0, 1.0)) -> np.ndarray:
        """A picture → (size, size, 3) uint8: the paper's volume render of ω (density from |ω|, colour from its
        direction, Γ drawn over it), or with ``mesh=True`` the shaded mesh; a 2D current's Fig. 3 plot."""
        current = self._need_current("render()")
        positive_int("size", size, 16)
        if current.dim == 2:
            fig = render_current_2d(current, None)
            return np.ascontiguousarray(figure_pixels(fig)[..., :3])
        loops = [lp.detach().cpu().double().numpy() for lp in current.loops]
        settings = DensitySettings()
        grid = proposal_grid(current, 40, settings)
        camera = fit_camera(grid.framing_points(), azimuth, elevation, 35.0, size, size)
        if mesh:
            return render_mesh(self._surface(None).mesh, loops, camera)
        return render_current(current, camera, samples=positive_int("samples", samples, 2), grid=grid,
                              settings=settings).over(background)

    # ---------------------------------------------------------------------------------------------- files
    def save(self, path: str | Path) -> Path:
        """Writes what ``path``'s suffix names: ``.ckpt`` the checkpoint (atomically; `deepcurrents.load`
        reads it back), ``.ply``/``.obj``/``.off``/``.stl``/``.glb`` the mesh, ``.png``/``.jpg`` the render. → path."""
        path = Path(path).expanduser()
        suffix = path.suffix.lower()
        if suffix == ".ckpt":
            if self.checkpoint is None:
                raise UserInputError(f"{self.name} has no checkpoint of its own (a family's member or interpolant "
                                     "lives in the family's): save the family, or its mesh (.ply).")
            _atomic_copy(self.checkpoint, path)
        elif suffix in MESH_SUFFIXES:
            path.parent.mkdir(parents=True, exist_ok=True)
            write_mesh(self.mesh(), path)
        elif suffix in IMAGE_SUFFIXES:
            path.parent.mkdir(parents=True, exist_ok=True)
            save_image(self.render(), path)
        else:
            raise UserInputError(f"save('{path}'): the suffix must name what to write: .ckpt (the checkpoint), "
                                 f"{', '.join(MESH_SUFFIXES)} (the mesh) or .png (the render).")
        return path


def _atomic_copy(source: Path, target: Path) -> None:
    """``source`` copied to ``target`` through a temporary file beside it: a crash leaves the old file or the new."""
    if target.resolve() == Path(source).resolve():
        return
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as out, open(source, "rb") as src:
            shutil.copyfileobj(src, out)
            out.flush()
            os.fsync(out.fileno())
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


InterpolationMode = Literal["latent", "boundary", "both"]


class FamilyResult:
    """A family of surfaces (paper §4.3, §5.3): one network, a latent code per training shape, Γ as the handle.

    Each of `member`, `interpolate` and `generate` gives a `Result` (f, ω, mesh,
    render, mass bound) of one surface of the family.
    """

    def __init__(self, module: torch.nn.Module, *, checkpoint: Path | None = None, run_dir: Path | None = None,
                 metrics: dict[str, Any] | None = None):
        self.module, self.checkpoint, self.run_dir = module, checkpoint, run_dir
        self.metrics: dict[str, Any] = dict(metrics or {})

    def __repr__(self) -> str:
        return f"FamilyResult({len(self)} shapes, checkpoint='{self.checkpoint}')"

    def __len__(self) -> int:
        return len(self.shapes)

    @property
    def shapes(self) -> list[str]:
        """The training shapes' names, in the order of their latent codes."""
        return [str(n) for n in self.module.hparams.shape_names]

    def _index(self, i: int, name: str) -> int:
        return self.module.check_shape_index(i, name)

    def _result(self, z: torch.Tensor, loops: list[np.ndarray], shapes: list[int], name: str) -> Result:
        module = self.module
        current = module.member(z, loops)

        def mesher(resolution: int | None):
            return module.mesh_member(current, module.meshing_bounds(shapes, loops), resolution)

        return Result(module, current, name=name, run_dir=self.run_dir, mesher=mesher)

    def member(self, i: int) -> Result:
        """Training shape ``i``: its own latent code and boundary."""
        i = self._index(i, "i")
        return self._result(self.module.latent(i), self.module.shape_loops(i), [i], self.shapes[i])

    def interpolate(self, a: int, b: int, t: float, mode: InterpolationMode = "latent") -> Result:
        """The member between shapes ``a`` and ``b`` at t ∈ [0, 1] (paper Fig. 6): ``latent`` z = (1 − t) z_a + t z_b
        on Γ_a; ``boundary`` Γ = (1 − t) Γ_a + t Γ_b (vertex by vertex) with z_a; ``both`` each interpolated."""
        a, b = self._index(a, "a"), self._index(b, "b")
        if isinstance(t, bool) or not isinstance(t, (int, float)) or not 0.0 <= t <= 1.0:
            raise ConfigError(f"t={t!r} must be a number in [0, 1].")
        if mode not in ("latent", "boundary", "both"):
            raise ConfigError(f"mode={mode!r} must be latent, boundary or both.")
        za, zb = self.module.latent(a), self.module.latent(b)
        z = za if mode == "boundary" else (1.0 - t) * za + t * zb
        loops_a = self.module.shape_loops(a)
        loops = loops_a if mode == "latent" else interpolate_loops(loops_a, self.module.shape_loops(b), float(t))
        return self._result(z, loops, [a, b], f"{self.shapes[a]}→{self.shapes[b]} ({mode} t={t:g})")

    def generate(self, curve: Any, latent: int = 0) -> Result:
        """A surface of the family for a new boundary (the boundary is the handle, paper §5.3): ``curve`` a list
        of (M_b, 3) loops (or a curve file path), one per boundary of the family, with training shape
        ``latent``'s code. The loops are matched to that shape's by their centroids and oriented like them."""
        k = self._index(latent, "latent")
        loops = align_loops(curve_loops(curve), self.module.shape_loops(k), "curve")
        return self._result(self.module.latent(k), loops, [k], f"{self.shapes[k]} on a new boundary")

    def save(self, path: str | Path) -> Path:
        """The family's checkpoint, copied atomically to ``path`` (``.ckpt``). → path."""
        path = Path(path).expanduser()
        if path.suffix.lower() != ".ckpt" or self.checkpoint is None:
            raise UserInputError(f"save('{path}'): a family saves its checkpoint (.ckpt); a member's mesh is "
                                 "family.member(i).save('shape.ply').")
        _atomic_copy(self.checkpoint, path)
        return path


def run_metrics(run_dir: Path | None) -> dict[str, Any]:
    """A run folder's ``metrics.json`` ({} when absent or unreadable)."""
    if run_dir is None or not (run_dir / "metrics.json").is_file():
        return {}
    try:
        value = json.loads((run_dir / "metrics.json").read_text())
    except (OSError, ValueError):
        return {}
    return value if isinstance(value, dict) else {}


def result_of(module: torch.nn.Module, checkpoint: Path, run_dir: Path | None,
              metrics: dict[str, Any] | None = None) -> Result | FamilyResult:
    """The result for a loaded module: a family, or one current (a minimal surface, a reconstruction, a grid
    current; the closest-point baseline without one)."""
    metrics = run_metrics(run_dir) if metrics is None else metrics
    if all(callable(getattr(module, n, None)) for n in ("member", "latent", "shape_loops")):
        return FamilyResult(module, checkpoint=checkpoint, run_dir=run_dir, metrics=metrics)
    current = getattr(module, "current", None)
    spec = (getattr(module, "hparams", None) or {}).get("boundary") or {}
    name = str(spec.get("name") or (module.run_config or {}).get("task_name") or type(module).__name__)
    return Result(module, current, name=name, checkpoint=checkpoint, run_dir=run_dir, metrics=metrics,
                  frame=file_frame(module))
