"""Meshing a neural current: a triangle mesh of its surface whose border lies on Γ (``extract_surface``),
or the curve of a 2D current (``extract_curve_2d``).

Rooms: ``surface`` (the driver, the same for every method, and ``METHODS``), ``method`` (what a method
provides), ``phase`` (the default: where the current's phase turns over), ``level_set`` (the paper's
f = s), ``border`` (the tube cut and the strips that zip the border onto Γ), ``curve_2d``. Border edges
and loops are pure mesh topology: ``deepcurrents.geometry.topology``.
"""

from deepcurrents.eval.meshing.border import clip_by_field, zip_to_loop
from deepcurrents.eval.meshing.curve_2d import CURVE_METHODS, extract_curve_2d
from deepcurrents.eval.meshing.level_set import level_on_boundary
from deepcurrents.eval.meshing.method import MeshMethod
from deepcurrents.eval.meshing.phase import current_phase
from deepcurrents.eval.meshing.surface import (
    MESH_METHOD_CHOICES,
    MESH_METHODS,
    METHODS,
    MeshingResult,
    extract_surface,
    flux_sign,
    grid_shape,
    mesh_method,
    mesh_region,
    region_of_interest,
)

__all__ = [
    "CURVE_METHODS", "MESH_METHODS", "MESH_METHOD_CHOICES", "METHODS", "MeshMethod", "MeshingResult", "clip_by_field",
    "current_phase", "extract_curve_2d", "extract_surface", "flux_sign", "grid_shape", "level_on_boundary",
    "mesh_method", "mesh_region", "region_of_interest", "zip_to_loop",
]
