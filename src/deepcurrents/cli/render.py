"""Pictures of any checkpoint: ``python -m deepcurrents.cli.render ckpt_path=…/last.ckpt [overrides]``.

3D currents: a volume render in the paper's style (density from |ω|, colour from ω's direction, Γ drawn
over it) → ``render.png``; ``turntable=true frames=36`` → ``render_turntable.gif`` (and ``.mp4`` where
ffmpeg is present); ``mesh=true`` also extracts the surface and draws it → ``render_mesh.png``.
2D currents: paper Fig. 3 (f as density, α as arrows, the curve; the metric as ellipses when the model
has one) → ``render.png`` (+ ``render_metric.png``).

Files go to a folder named after the checkpoint beside it (``out_dir=`` to choose). Sizes default to the
``cpu`` preset on a CPU (seconds a frame) and ``gpu`` on a GPU; any size given explicitly wins.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import hydra
import numpy as np
from omegaconf import MISSING, DictConfig

from deepcurrents.cli.common import output_dir, plain_file_name, register_app, run_app
from deepcurrents.errors import ConfigError, positive_int
from deepcurrents.eval.meshing import extract_surface
from deepcurrents.eval.render import (
    Camera,
    DensitySettings,
    fit_camera,
    proposal_grid,
    render_current,
    render_current_2d,
    render_mesh,
    save_gif,
    save_image,
    save_mp4,
)
from deepcurrents.models.current_module import reported_mesh_area
from deepcurrents.models.loading import load_module, mesh_settings, resolve_device, viewable_current

log = logging.getLogger("deepcurrents.render")

# image side (pixels), ω samples per ray, proposal grid resolution; turntable frames are smaller on a CPU
PRESETS = {
    "cpu": {"size": 128, "samples": 32, "grid": 32, "turntable_size": 96},
    "gpu": {"size": 640, "samples": 128, "grid": 96, "turntable_size": 480},
}


@dataclass
class CameraConfig:
    azimuth: float = 35.0  # degrees, z up (matplotlib's convention)
    elevation: float = 25.0
    distance: float | None = None  # None: fit the current in view
    fov: float = 35.0  # vertical field of view, degrees
    target: list[float] | None = None  # None: the centre of the current's support
    width: int | None = None  # None: from the preset
    height: int | None = None


@dataclass
class RenderConfig:
    ckpt_path: str = MISSING
    out_dir: str | None = None
    name: str = "render"  # file stem
    device: str = "auto"
    preset: str = "auto"  # auto | cpu | gpu
    shape: int | None = None  # families: which training shape (default 0)
    samples: int | None = None
    grid: int | None = None
    gain: float = 3.0  # opacity of an ideal sheet seen face-on: 1 − exp(−gain)
    floor: float = 2.5e-3  # |ω| below this is transparent
    shading: float = 0.0
    curves: bool = True
    background: list[float] = field(default_factory=lambda: [1.0, 1.0, 1.0])
    transparent: bool = False
    turntable: bool = False
    frames: int = 36
    fps: float = 12.0
    mesh: bool = False
    resolution: int | None = None  # marching-cubes resolution for mesh=true (default: the run's)
    camera: CameraConfig = field(default_factory=CameraConfig)


register_app("render", RenderConfig, __doc__)


def _sizes(cfg: DictConfig, device) -> dict:
    preset = cfg.preset if cfg.preset != "auto" else ("gpu" if device.type == "cuda" else "cpu")
    if preset not in PRESETS:
        raise ConfigError(f"preset='{cfg.preset}' must be auto, cpu or gpu.")
    p = PRESETS[preset]
    side = p["turntable_size"] if cfg.turntable else p["size"]
    return {
        "width": positive_int("camera.width", cfg.camera.width if cfg.camera.width is not None else side),
        "height": positive_int("camera.height", cfg.camera.height if cfg.camera.height is not None else side),
        "samples": positive_int("samples", cfg.samples if cfg.samples is not None else p["samples"], 2),
        "grid": positive_int("grid", cfg.grid if cfg.grid is not None else p["grid"], 4),
    }


def make_camera(cfg: DictConfig, points: np.ndarray, width: int, height: int, tight: bool) -> Camera:
    """The configured camera; unset target/distance fitted to the points (N, 3) that frame the current."""
    c = cfg.camera
    fitted = fit_camera(points, c.azimuth, c.elevation, c.fov, width, height, tight=tight)
    target = tuple(float(v) for v in c.target) if c.target is not None else fitted.target
    if len(target) != 3:
        raise ConfigError(f"camera.target={list(c.target)} must be three numbers [x, y, z].")
    distance = float(c.distance) if c.distance is not None else fitted.distance
    return Camera(float(c.azimuth), float(c.elevation), distance, float(c.fov), target, width, height)


def metric_of(module) -> Callable | None:
    """The metric B_x of a 2D run, for Fig. 3d's ellipses: ``module.metric_fn`` or, rebuilt from the run's
    config, its DataModule's ``metric_fn`` (x (N, 2) → B (N, 2, 2)); None for the Euclidean metric."""
    if callable(getattr(module, "metric_fn", None)):
        return module.metric_fn
    data = (getattr(module, "run_config", None) or {}).get("data")
    if not isinstance(data, dict) or "_target_" not in data:
        return None
    try:
        datamodule = hydra.utils.instantiate(data, _convert_="all")
    except Exception as err:  # the run's data may be gone (moved files): draw without the metric
        log.warning("Could not rebuild the run's data for its metric (%s); drawing without it.", err)
        return None
    metric_fn = getattr(datamodule, "metric_fn", None)
    return metric_fn if callable(metric_fn) else None


def render_checkpoint(cfg: DictConfig) -> list:
    """The app's body. → the files written."""
    device = resolve_device(cfg.device)
    name = plain_file_name(cfg.name) or "render"
    positive_int("frames", cfg.frames)
    if cfg.resolution is not None:  # as extract refuses it: 0 was a ZeroDivisionError inside the meshing
        positive_int("resolution", cfg.resolution, 8)
    if not cfg.fps > 0:
        raise ConfigError(f"fps={cfg.fps} must be positive.")
    sizes = _sizes(cfg, device)
    module = load_module(cfg.ckpt_path, map_location=device)
    current = viewable_current(module, cfg.ckpt_path, cfg.shape)
    out = output_dir(cfg.ckpt_path, cfg.out_dir, cfg.shape)
    written = []
    if current.dim == 2:
        if cfg.turntable or cfg.mesh:
            raise ConfigError("turntable=true and mesh=true need a 3D current; this checkpoint's is 2D.")
        metric_fn = metric_of(module)
        render_current_2d(current, out / f"{name}.png")
        written.append(out / f"{name}.png")
        if callable(metric_fn):
            render_current_2d(current, out / f"{name}_metric.png", metric_fn=metric_fn, show_alpha=False)
            written.append(out / f"{name}_metric.png")
        return written

    settings = DensitySettings(gain=float(cfg.gain), floor=float(cfg.floor), shading=float(cfg.shading))
    start = time.perf_counter()
    grid = proposal_grid(current, sizes["grid"], settings)
    camera = make_camera(cfg, grid.framing_points(), sizes["width"], sizes["height"], tight=not cfg.turntable)
    kwargs = {"samples": sizes["samples"], "grid": grid, "settings": settings, "curves": bool(cfg.curves)}
    loops = [lp.detach().cpu().double().numpy() for lp in current.loops]
    if cfg.turntable:
        frames = []
        for k, cam in enumerate(camera.turntable(cfg.frames)):
            frames.append(render_current(current, cam, **kwargs).over(cfg.background))
            log.info("frame %d/%d", k + 1, cfg.frames)
        written.append(save_gif(frames, out / f"{name}_turntable.gif", cfg.fps))
        mp4 = save_mp4(frames, out / f"{name}_turntable.mp4", cfg.fps)
        if mp4 is not None:
            written.append(mp4)
    else:
        image = render_current(current, camera, **kwargs)
        pixels = image.rgba() if cfg.transparent else image.over(cfg.background)
        written.append(save_image(pixels, out / f"{name}.png"))
    log.info("volume render: %.1f s", time.perf_counter() - start)
    if cfg.mesh:
        result = extract_surface(current, **mesh_settings(module, cfg.shape, resolution=cfg.resolution))
        title = f"area {reported_mesh_area(module, result.mesh.area):.4g}"  # as the run's own mesh.png
        if cfg.turntable:
            frames = [render_mesh(result.mesh, loops, cam) for cam in camera.turntable(cfg.frames)]
            written.append(save_gif(frames, out / f"{name}_mesh_turntable.gif", cfg.fps))
        else:
            path = out / f"{name}_mesh.png"
            render_mesh(result.mesh, loops, camera, path, title=title)
            written.append(path)
    return written


@hydra.main(version_base="1.3", config_path=None, config_name="render")
def main(cfg: DictConfig) -> None:
    written = run_app(render_checkpoint, cfg)
    for path in written:
        print(path)


if __name__ == "__main__":
    main()
