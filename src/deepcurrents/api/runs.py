"""Training from Python: `minimal_surface` and `reconstruct` compose the same Hydra configs as
``python train.py`` (an experiment, a preset, a recipe, overrides) and run them through the same runner, so the
same settings and seed give the same metrics; `load` opens any checkpoint the project writes."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import trimesh
from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from hydra.errors import ConfigCompositionException, OverrideParseException
from omegaconf import DictConfig, OmegaConf

from deepcurrents.api.inputs import (
    array_loops,
    curve_loops,
    existing_file,
    is_path,
    oriented_points,
    write_curve,
    write_oriented_points,
    write_target_mesh,
)
from deepcurrents.api.results import FamilyResult, Result, result_of
from deepcurrents.errors import ConfigError, UserInputError, number_at_least, positive_int
from deepcurrents.experiments.config import CONFIG_DIR, validate_config
from deepcurrents.experiments.run_dir import make_run_dir
from deepcurrents.experiments.runner import train
from deepcurrents.geometry.curves import NAMED_CURVES
from deepcurrents.models.loading import CheckpointError, load_module, resolve_device

# A function that writes the run's inputs into its folder and returns the overrides that name them.
InputWriter = Callable[[Path], list[str]]


def quoted(path: Path | str) -> str:
    """A path as a Hydra override value (quoted: spaces, '=' and commas are the grammar's)."""
    return "'" + str(path).replace("\\", "\\\\").replace("'", "\\'") + "'"


@contextmanager
def hydra_configs():
    """Hydra initialised on the project's configs for the block (what a suite's members compose with); a Hydra
    already initialised by the caller (an app of their own) is put back afterwards."""
    instance = GlobalHydra.instance()
    before = instance.hydra if instance.is_initialized() else None
    instance.clear()
    try:
        with initialize_config_dir(config_dir=CONFIG_DIR, version_base="1.3"):
            yield
    finally:
        instance.clear()
        if before is not None:
            instance.initialize(before)


def compose_run(overrides: Sequence[str]) -> DictConfig:
    """The root config ``train`` with these overrides, or ConfigError in one sentence (an unknown experiment,
    preset or recipe, a setting that does not exist, a malformed override)."""
    try:
        return compose(config_name="train", overrides=list(overrides))
    except (ConfigCompositionException, OverrideParseException) as err:
        lines = [line.strip() for line in str(err).splitlines() if line.strip()]
        options = [line for line in lines[1:] if not line.startswith("Available options")]
        said = lines[0].rstrip(".") if lines else type(err).__name__
        if options and "Available options" in str(err):
            said += f" (available: {', '.join(options)})"
        raise ConfigError(f"The settings {' '.join(overrides)} cannot be composed: {said}.") from None


def run_settings(preset: str, recipe: str | None, steps: int | None, max_time: float | None,
                 overrides: Sequence[str], progress: bool) -> list[str]:
    """The overrides the keyword arguments stand for, checked (one sentence for a wrong type)."""
    if not isinstance(preset, str) or not preset:
        raise ConfigError(f"preset={preset!r} must be a preset's name (cpu, paper, …).")
    if recipe is not None and (not isinstance(recipe, str) or not recipe):
        raise ConfigError(f"recipe={recipe!r} must be a recipe's name (sharp, fast, …) or None.")
    if isinstance(overrides, str) or not all(isinstance(o, str) for o in overrides):
        raise ConfigError(f"overrides={overrides!r} must be a list of strings such as ['model.optim.lr=1e-3'].")
    settings = [f"preset={preset}"]
    if recipe is not None:
        settings.append(f"recipe={recipe}")
    if steps is not None:
        settings.append(f"trainer.max_steps={positive_int('steps', steps)}")
    if max_time is not None:
        settings.append(f"trainer.max_time={number_at_least('max_time', max_time, strict=True):g}")
    if not progress:
        settings.append("trainer.enable_progress_bar=false")
    return settings


def default_run_dir(task_name: str) -> Path:
    """``outputs/<task>/<time>`` as Hydra names a run's folder, made unique within the second."""
    base = Path("outputs") / task_name / time.strftime("%Y-%m-%d_%H-%M-%S")
    path, k = base, 1
    while path.exists():
        path, k = base.with_name(f"{base.name}_{k}"), k + 1
    return path


def record_command(out_dir: Path, cfg: DictConfig, overrides: list[str]) -> None:
    """The run's record as the command line leaves it (``.hydra/config.yaml``, ``.hydra/overrides.yaml``): the
    same run again is ``python train.py <overrides>``."""
    record = out_dir / ".hydra"
    record.mkdir(parents=True, exist_ok=True)
    (record / "config.yaml").write_text(OmegaConf.to_yaml(cfg))
    (record / "overrides.yaml").write_text(OmegaConf.to_yaml(OmegaConf.create(list(overrides))))


def run(experiment: str, problem: list[str], inputs: InputWriter | None, *, preset: str = "cpu",
        recipe: str | None = None, steps: int | None = None, max_time: float | None = None,
        overrides: Sequence[str] = (), out_dir: str | Path | None = None, progress: bool = True,
        ) -> Result | FamilyResult | dict[str, Result | FamilyResult]:
    """Trains ``experiment`` on the problem its overrides (and the files ``inputs`` writes) name, as
    ``python train.py experiment=… <problem> <settings> <overrides>`` does, into ``out_dir``. → its result (a
    suite's: its members' by name)."""
    settings = run_settings(preset, recipe, steps, max_time, overrides, progress)
    head = [f"experiment={experiment}", *problem]
    with hydra_configs():
        first = compose_run([*head, *settings, *overrides])  # a wrong name or setting said before any folder
        validate_config(first)
        task = str(first.task_name)
        folder = Path(out_dir).expanduser() if out_dir is not None else default_run_dir(task)
        make_run_dir(folder)
        files = inputs(folder.resolve()) if inputs is not None else []
        command = [*head, *files, *settings, *overrides]
        cfg = compose_run([*command, f"paths.output_dir={quoted(folder)}"])
        record_command(folder, cfg, command)
        try:
            metrics = train(cfg, out_dir=folder, overrides=command)
        except SystemExit as stop:  # Ctrl-C or SIGTERM: the runner kept checkpoints/last.ckpt
            raise KeyboardInterrupt(f"Training stopped (status {stop.code}); {folder / 'checkpoints' / 'last.ckpt'} "
                                    "holds it, and the same call with overrides=['ckpt_path=auto'] and this "
                                    "out_dir continues it.") from None
    device = resolve_device("auto")
    if cfg.get("suite"):
        return {str(m.name): load(folder / str(m.name), device=device) for m in cfg.suite.runs}
    last = folder / "checkpoints" / "last.ckpt"
    return result_of(load_module(last, map_location=device), last, folder, metrics)


def train_experiment(experiment: str, *, preset: str = "cpu", recipe: str | None = None,
                     max_time: float | None = None, steps: int | None = None, overrides: Sequence[str] = (),
                     out_dir: str | Path | None = None, progress: bool = True,
                     ) -> Result | FamilyResult | dict[str, Result | FamilyResult]:
    """Any experiment of ``conf/experiment/`` (``fig4``, ``table1``, ``latent_hands``, ``minimal_grid``, …), as
    ``python train.py experiment=<name> preset=<preset> <overrides>`` runs it.

    Returns:
        The run's `Result` (a `FamilyResult` for a family), or for a suite (Fig. 4, Table 1, the ablation) a
        dict of its members' results by name, with its table and figure written into ``out_dir``.
    """
    if not isinstance(experiment, str) or not experiment:
        raise ConfigError(f"experiment={experiment!r} must be the name of a file in conf/experiment/.")
    return run(experiment, [], None, preset=preset, recipe=recipe, steps=steps, max_time=max_time,
               overrides=overrides, out_dir=out_dir, progress=progress)


def minimal_surface(curve: Any, *, preset: str = "cpu", recipe: str | None = None, max_time: float | None = None,
                    steps: int | None = None, overrides: Sequence[str] = (), out_dir: str | Path | None = None,
                    progress: bool = True) -> Result:
    """The minimal surface spanning a closed curve (paper §5.1), trained and evaluated.

    Args:
        curve: an (M, 3) array of one closed loop's vertices (NumPy, torch or nested lists; the last vertex joins
            the first), a list of such loops (a link), a curve file (``.obj`` with one ``l`` per loop,
            ``.txt``/``.npy`` with one ``x y z`` row per vertex), or a named curve (trefoil, hopf, borromean,
            circle, enneper, …). Any units: a curve beyond the box is moved into it and the results reported in
            its own coordinates.
        preset: the size of the run (``cpu``: minutes on a laptop; ``paper``: the authors' settings).
        recipe: a training recipe on top of it (e.g. ``sharp``, the fast sharpened one), or None.
        max_time: a wall-clock budget for training, in seconds (the first of it and ``steps`` stops it).
        steps: training steps (default: the preset's).
        overrides: further Hydra overrides, as on the command line (``["model.optim.lr=1e-3", "seed=1"]``).
        out_dir: the run's folder (default ``outputs/<task>/<time>``); it gets what ``train.py`` writes
            (metrics.json, mesh.ply, pictures, checkpoints/last.ckpt) and, for a curve held in arrays, curve.obj.
        progress: show the progress bar (it works in a notebook).

    Returns:
        The trained current, a `Result` with ``mesh()``, ``f(x)``, ``omega(x)``, ``mass_bound()``, ``render()``
        and ``metrics``.

    Raises:
        UserInputError: a curve or setting that cannot be used, in one sentence (before anything trains).
    """
    inputs: InputWriter | None = None
    if is_path(curve) and str(curve).strip().lower() in NAMED_CURVES:
        name = str(curve).strip().lower()
        own = (Path(CONFIG_DIR) / "experiment" / f"minimal_{name}.yaml").is_file()  # the paper's curves' own
        experiment, problem = (f"minimal_{name}", []) if own else ("minimal_curve", [f"data.curve={name}"])
    elif is_path(curve):
        curve_loops(str(Path(curve).expanduser()), domain=np.inf)  # a file that cannot be read: said before any folder
        experiment, problem = "minimal_curve", [f"data.curve={quoted(Path(curve).expanduser().resolve())}"]
    else:
        loops = array_loops(curve)  # checked before a folder is made for them
        experiment, problem = "minimal_curve", []

        def inputs(folder: Path) -> list[str]:
            return [f"data.curve={quoted(write_curve(loops, folder))}"]

    return run(experiment, problem, inputs, preset=preset, recipe=recipe, steps=steps, max_time=max_time,
               overrides=overrides, out_dir=out_dir, progress=progress)


def reconstruct(target: Any, *, boundary: Any = None, preset: str = "cpu", recipe: str | None = None,
                max_time: float | None = None, steps: int | None = None, overrides: Sequence[str] = (),
                out_dir: str | Path | None = None, progress: bool = True) -> Result:
    """A surface with boundary reconstructed from a target (paper §4.2, §5.2), trained and evaluated.

    Args:
        target: a triangle mesh with boundary (a mesh file or a ``trimesh.Trimesh``; Γ is its border), or an
            oriented point cloud: ``(points, normals)``, two (P, 3) arrays, or a point-cloud file (``.ply`` with
            normals, ``.xyz`` rows ``x y z nx ny nz``) when ``boundary`` is given.
        boundary: a point cloud's Γ: loops as arrays (an (M, 3) array or a list of them) or a curve file,
            oriented so that the normals follow the right-hand rule around it. A mesh's Γ is its own border.

    The other arguments (preset, recipe, max_time, steps, overrides, out_dir, progress) are
    `minimal_surface`'s.

    Returns:
        The trained current, a `Result` whose ``metrics`` hold the run's UCD to the target.
    """
    if boundary is None:
        if isinstance(target, tuple):
            raise UserInputError("reconstruct((points, normals)) needs boundary=…: the loops Γ of the surface (an "
                                 "(M, 3) array, a list of them, or a curve file).")
        if is_path(target):
            problem, inputs = [f"data.mesh={quoted(existing_file(target, 'target'))}"], None
        elif isinstance(target, trimesh.Trimesh):
            if len(target.faces) == 0:
                raise UserInputError("target is a trimesh.Trimesh without faces; give a triangle mesh with a "
                                     "boundary.")
            mesh, problem = target, []

            def inputs(folder: Path) -> list[str]:
                return [f"data.mesh={quoted(write_target_mesh(mesh, folder))}"]
        else:
            raise UserInputError(f"target is a {type(target).__name__}; give a mesh file, a trimesh.Trimesh, or "
                                 "(points, normals) with boundary=….")
        return run("recon_mesh", problem, inputs, preset=preset, recipe=recipe, steps=steps, max_time=max_time,
                   overrides=overrides, out_dir=out_dir, progress=progress)
    if isinstance(target, trimesh.Trimesh):
        raise UserInputError("boundary=… is a point cloud's: a mesh's Γ is its own border; leave boundary unset.")
    if not (is_path(target) or isinstance(target, tuple) and len(target) == 2):
        raise UserInputError(f"target is a {type(target).__name__}; with boundary=… give (points, normals) or a "
                             "point-cloud file.")
    # checked before a folder is made for them
    rows, cloud = (None, existing_file(target, "target")) if is_path(target) else (oriented_points(target), None)
    loops, rim = (None, existing_file(boundary, "boundary")) if is_path(boundary) else \
        (array_loops(boundary, "boundary"), None)

    def inputs(folder: Path) -> list[str]:
        points = cloud if rows is None else write_oriented_points(rows, folder)
        curve = rim if loops is None else write_curve(loops, folder, "boundary")
        return [f"data.points={quoted(points)}", f"data.curve={quoted(curve)}"]

    return run("recon_points", [], inputs, preset=preset, recipe=recipe, steps=steps, max_time=max_time,
               overrides=overrides, out_dir=out_dir, progress=progress)


def load(path: str | Path, *, device: str = "auto") -> Result | FamilyResult:
    """Any checkpoint the project writes (a minimal surface, a reconstruction, the grid method's current, the
    closest-point baseline, a family), or a run's folder (its ``checkpoints/last.ckpt``).

    Read safely: only tensors and plain data are unpickled, so a crafted file cannot run code; a file that is not
    a DeepCurrents checkpoint is refused in one sentence (`CheckpointError`).

    Args:
        path: the checkpoint file or the run folder.
        device: ``auto`` (a CUDA GPU where there is one), ``cpu``, ``cuda``, ``cuda:1``, ….

    Returns:
        A `Result` for one current, a `FamilyResult` for a family.
    """
    given = Path(path).expanduser()
    if given.is_dir():
        found = next((p for p in (given / "checkpoints" / "last.ckpt", given / "last.ckpt") if p.is_file()), None)
        if found is None:
            raise CheckpointError(f"'{path}' is a folder without checkpoints/last.ckpt; give a checkpoint file or a "
                                  "run's folder.")
        given = found
    module = load_module(given, map_location=resolve_device(device))
    run_dir = given.parent.parent if given.parent.name == "checkpoints" else None
    return result_of(module, given, run_dir)

