"""The pinhole camera of the volume renderer, and fitting one to what should be seen."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import torch

from deepcurrents.errors import ConfigError


@dataclass(frozen=True)
class Camera:
    """A pinhole camera orbiting ``target`` (matplotlib's convention, as ``plots.plot_mesh``: z is up, the
    eye is at azimuth/elevation in degrees, ``distance`` away). ``fov`` is the vertical field of view."""

    azimuth: float = 35.0
    elevation: float = 25.0
    distance: float = 3.0
    fov: float = 35.0
    target: tuple[float, float, float] = (0.0, 0.0, 0.0)
    width: int = 256
    height: int = 256

    def __post_init__(self):
        for key in ("width", "height"):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise ConfigError(f"camera.{key}={value!r} must be a positive integer (pixels).")
        check_fov(self.fov)
        if not (math.isfinite(float(self.distance)) and float(self.distance) > 0):
            raise ConfigError(f"camera.distance={self.distance!r} must be a positive number.")

    @property
    def focal(self) -> float:
        """Focal length in pixels."""
        return 0.5 * self.height / math.tan(math.radians(self.fov) / 2)

    def basis(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(eye, right, up, forward), each (3,) float64; right/up/forward orthonormal."""
        a, e = math.radians(self.azimuth), math.radians(self.elevation)
        back = np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)])
        eye = np.asarray(self.target, dtype=np.float64) + self.distance * back
        forward = -back
        world_up = np.array([0.0, 0.0, 1.0])
        if abs(forward @ world_up) > 0.999:  # looking straight down or up: the azimuth sets the image's up
            world_up = np.array([-math.cos(a), -math.sin(a), 0.0]) * np.sign(forward[2])
        right = np.cross(forward, world_up)
        right /= np.linalg.norm(right)
        up = np.cross(right, forward)
        return eye, right, up, forward

    def rays(self, device: torch.device | str = "cpu") -> tuple[torch.Tensor, torch.Tensor]:
        """One ray per pixel through its centre, row-major from the top-left.

        → (origins (H·W, 3), unit directions (H·W, 3)), float32 on ``device``.
        """
        eye, right, up, forward = self.basis()
        cols = (np.arange(self.width) + 0.5 - 0.5 * self.width) / self.focal
        rows = (0.5 * self.height - (np.arange(self.height) + 0.5)) / self.focal
        v, u = np.meshgrid(rows, cols, indexing="ij")
        d = forward + u.reshape(-1, 1) * right + v.reshape(-1, 1) * up
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        dirs = torch.as_tensor(d, dtype=torch.float32, device=device)
        origins = torch.as_tensor(eye, dtype=torch.float32, device=device).expand_as(dirs)
        return origins, dirs

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Pixel coordinates of 3D points: (col (N,), row (N,), distance from the eye (N,)); points behind
        the camera get NaN pixel coordinates."""
        eye, right, up, forward = self.basis()
        rel = np.asarray(points, dtype=np.float64) - eye
        z = rel @ forward
        with np.errstate(divide="ignore", invalid="ignore"):
            zs = np.where(z > 1e-9, z, np.nan)
            col = 0.5 * self.width + self.focal * (rel @ right) / zs - 0.5
            row = 0.5 * self.height - self.focal * (rel @ up) / zs - 0.5
        return col, row, np.linalg.norm(rel, axis=1)

    def orbit(self, azimuth: float) -> Camera:
        """The same camera at another azimuth (degrees)."""
        return replace(self, azimuth=float(azimuth))

    def turntable(self, frames: int) -> list[Camera]:
        """``frames`` cameras at evenly spaced azimuths, starting at this one's (a turntable's frames)."""
        if isinstance(frames, bool) or not isinstance(frames, (int, np.integer)) or frames < 1:
            raise ConfigError(f"frames={frames!r} must be a positive integer.")
        return [self.orbit(self.azimuth + 360.0 * k / frames) for k in range(int(frames))]


def check_fov(fov: float) -> float:
    """``fov`` if it is a field of view in degrees strictly between 0 and 180, else one sentence."""
    if not 0.0 < float(fov) < 180.0:
        raise ConfigError(f"camera.fov={fov!r} must be an angle in degrees between 0 and 180.")
    return float(fov)


def fit_camera(points: np.ndarray, azimuth: float = 35.0, elevation: float = 25.0, fov: float = 35.0,
               width: int = 256, height: int = 256, margin: float = 1.08, tight: bool = True) -> Camera:
    """A camera at the given angles looking at the centre of the points' bounding box.

    points: (N, 3), e.g. a box's two corners (2, 3) or the visible part of a current (ProposalGrid.frame).
    ``tight``: as close as the points allow from these angles (stills); otherwise far enough to see their
    bounding sphere from any angle (turntables keep one distance for every frame).
    """
    check_fov(fov)  # before the distance that divides by its sine
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    lo_box, hi_box = points.min(0), points.max(0)
    center = 0.5 * (lo_box + hi_box)
    radius = max(float(np.linalg.norm(points - center, axis=1).max()), 1e-3)
    # half-angle of the narrower side of the image: the bounding sphere must fit in it
    half = math.atan(math.tan(math.radians(fov) / 2) * min(1.0, width / height))
    far = margin * radius / math.sin(half)
    camera = Camera(azimuth, elevation, far, fov, tuple(center.tolist()), width, height)
    if not tight:
        return camera

    def fits(distance: float) -> bool:
        col, row, _ = replace(camera, distance=distance).project(points)
        if not np.all(np.isfinite(col)):
            return False
        spread_x = np.abs(col + 0.5 - 0.5 * width).max() / width
        spread_y = np.abs(row + 0.5 - 0.5 * height).max() / height
        return max(spread_x, spread_y) * margin <= 0.5

    lo, hi = radius * 1e-3, far  # the sphere's distance always fits; bisect down to the tightest
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if fits(mid) else (mid, hi)
    return replace(camera, distance=hi)
