"""Pictures of neural currents: ``volume`` (the paper's volume rendering: density from |ω|, colour from ω's
direction), ``camera`` (the pinhole camera and fitting it), ``media`` (PNG, GIF and MP4 writers),
``figures`` (matplotlib pictures of an extracted mesh and of a 2D current). Which current of a model is
shown is the models' business (``models.loading.current_to_view``)."""

from deepcurrents.eval.render.camera import Camera, fit_camera
from deepcurrents.eval.render.figures import render_current_2d, render_mesh
from deepcurrents.eval.render.media import ffmpeg_executable, save_gif, save_image, save_mp4
from deepcurrents.eval.render.volume import (
    DensitySettings,
    ProposalGrid,
    Rendering,
    draw_curves,
    proposal_grid,
    render_current,
)

__all__ = [
    "Camera", "DensitySettings", "ProposalGrid", "Rendering", "draw_curves", "ffmpeg_executable", "fit_camera",
    "proposal_grid", "render_current", "render_current_2d", "render_mesh", "save_gif", "save_image", "save_mp4",
]
