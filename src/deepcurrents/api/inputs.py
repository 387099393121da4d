"""The Python API's inputs as the files a run reads: a curve held in arrays becomes ``curve.obj``, a
``trimesh.Trimesh`` ``target.ply``, an oriented point cloud ``points.npy``, all inside the run's folder, so the
run is the command line's (``data.curve=…/curve.obj``) and can be repeated from its folder alone."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import trimesh

from deepcurrents.errors import UserInputError
from deepcurrents.geometry.curves import NAMED_CURVES, load_boundary, write_curve_file
from deepcurrents.geometry.meshes import write_mesh


def _array(value: Any) -> np.ndarray | None:
    """``value`` as a float64 array (NumPy, torch, nested lists of numbers), or None where it is not one."""
    if hasattr(value, "detach") and hasattr(value, "cpu"):  # a torch tensor
        value = value.detach().cpu().numpy()
    try:
        return np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):  # ragged lists (loops of different lengths), strings, objects
        return None


def _loop(value: Any, name: str) -> np.ndarray:
    loop = _array(value)
    if loop is None or loop.ndim != 2 or loop.shape[1] != 3:
        shape = "not an array of numbers" if loop is None else f"shape {tuple(loop.shape)}"
        raise UserInputError(f"{name} has {shape}; a closed loop is an (M, 3) array of its vertices, in order.")
    if len(loop) < 3:
        raise UserInputError(f"{name} has {len(loop)} vertices; a closed loop needs at least 3.")
    if not np.isfinite(loop).all():
        raise UserInputError(f"{name} holds NaN or infinite coordinates.")
    return loop


def is_path(value: Any) -> bool:
    return isinstance(value, (str, Path))


def existing_file(path: str | Path, name: str) -> Path:
    """``path`` expanded and resolved, or UserInputError naming ``name`` when no such file exists (said before a run
    folder is made for it)."""
    file = Path(path).expanduser().resolve()
    if not file.is_file():
        raise UserInputError(f"{name}='{path}' is not a file.")
    return file


def array_loops(curve: Any, name: str = "curve") -> list[np.ndarray]:
    """The loops of a curve given as arrays: one (M, 3) array (one loop), a (B, M, 3) array, or a list of (M_i, 3)
    arrays; each checked (shape, at least 3 vertices, finite), or UserInputError naming it."""
    whole = _array(curve)
    if whole is not None and whole.ndim == 2:
        return [_loop(whole, name)]
    if whole is not None and whole.ndim == 3:
        return [_loop(lp, f"{name}[{i}]") for i, lp in enumerate(whole)]
    if isinstance(curve, (list, tuple)) and curve:
        return [_loop(lp, f"{name}[{i}]") for i, lp in enumerate(curve)]
    shape = "" if whole is None else f" (an array of shape {tuple(whole.shape)})"
    raise UserInputError(f"{name}{shape} must be an (M, 3) array of a closed loop's vertices, a list of such "
                         "loops, a curve file or a named curve (" + ", ".join(sorted(NAMED_CURVES)) + ").")


def curve_loops(curve: Any, name: str = "curve", domain: float = 1.0) -> list[np.ndarray]:
    """Loops from arrays (`array_loops`) or from a curve file or named curve, as its coordinates say (a
    file's loops must lie within ``domain`` of the origin in each coordinate)."""
    if is_path(curve):
        return [np.asarray(lp, np.float64) for lp in load_boundary(str(curve), setting=name, domain=domain).loops]
    return array_loops(curve, name)


def write_curve(loops: list[np.ndarray], folder: Path, name: str = "curve") -> Path:
    """Loops (checked by `array_loops`) written to ``folder/<name>.obj`` (one ``l`` per loop, read back
    exactly). → the file."""
    path = folder / f"{name}.obj"
    write_curve_file(path, loops)
    return path


def write_target_mesh(mesh: trimesh.Trimesh, folder: Path) -> Path:
    """A target mesh held in memory written to ``folder/target.ply`` (float64 vertices). → the file."""
    path = folder / "target.ply"
    write_mesh(trimesh.Trimesh(np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces), process=False), path)
    return path


def oriented_points(target: tuple[Any, Any]) -> np.ndarray:
    """An oriented point cloud (points (P, 3), normals (P, 3)) checked and joined as rows ``x y z nx ny nz``
    (P, 6), or UserInputError naming what is wrong."""
    points, normals = (_array(v) for v in target)
    for value, what in ((points, "points"), (normals, "normals")):
        if value is None or value.ndim != 2 or value.shape[1] != 3:
            shape = "not an array of numbers" if value is None else f"shape {tuple(value.shape)}"
            raise UserInputError(f"target's {what} has {shape}; give (points, normals) as two (P, 3) arrays.")
        if not np.isfinite(value).all():
            raise UserInputError(f"target's {what} hold NaN or infinite values.")
    if len(points) != len(normals):
        raise UserInputError(f"target has {len(points)} points but {len(normals)} normals; give one normal per "
                             "point.")
    return np.concatenate([points, normals], axis=1)


def write_oriented_points(rows: np.ndarray, folder: Path) -> Path:
    """Rows ``x y z nx ny nz`` (`oriented_points`) written to ``folder/points.npy``, what ``data.points``
    reads. → the file."""
    path = folder / "points.npy"
    np.save(path, rows)
    return path
