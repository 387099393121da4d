"""Writing pictures and turntables: PNG (or any format imageio knows), looping GIF, H.264 MP4 through ffmpeg."""

from __future__ import annotations

import logging
import shutil
import subprocess
from collections.abc import Sequence
from pathlib import Path

import numpy as np

log = logging.getLogger(__name__)


def save_image(image: np.ndarray, path: str | Path) -> Path:
    """Writes an (H, W, 3|4) uint8 array as PNG (or any format imageio knows from the suffix)."""
    import imageio.v3 as iio

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    iio.imwrite(path, image)
    return path


def save_gif(frames: Sequence[np.ndarray], path: str | Path, fps: float = 12.0) -> Path:
    """An endlessly looping GIF of (H, W, 3) uint8 frames."""
    import imageio.v3 as iio

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    iio.imwrite(path, np.stack(frames), extension=".gif", duration=1000.0 / fps, loop=0)
    return path


def ffmpeg_executable() -> str | None:
    """The ffmpeg binary: imageio-ffmpeg's (the ``media`` extra) or one on PATH; None if there is none."""
    try:
        import imageio_ffmpeg

        return imageio_ffmpeg.get_ffmpeg_exe()
    except (ImportError, RuntimeError):
        return shutil.which("ffmpeg")


def save_mp4(frames: Sequence[np.ndarray], path: str | Path, fps: float = 24.0) -> Path | None:
    """An H.264 MP4 of (H, W, 3) uint8 frames through ffmpeg; None (and a log line) where ffmpeg is absent."""
    exe = ffmpeg_executable()
    if exe is None:
        log.info("ffmpeg not found (pip install 'deepcurrents[media]'); no MP4 written.")
        return None
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    h, w = frames[0].shape[:2]
    cmd = [exe, "-y", "-loglevel", "error", "-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{w}x{h}",
           "-r", str(fps), "-i", "-", "-an", "-c:v", "libx264", "-pix_fmt", "yuv420p",
           "-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2", str(path)]  # yuv420p needs even sizes
    data = np.ascontiguousarray(np.stack(frames)[..., :3]).tobytes()
    result = subprocess.run(cmd, input=data, capture_output=True)
    if result.returncode != 0:
        log.warning("ffmpeg failed (%s); no MP4 written.", result.stderr.decode(errors="replace").strip())
        return None
    return path
