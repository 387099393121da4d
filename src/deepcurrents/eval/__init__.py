"""Evaluation of a trained current: ``meshing/`` (its surface as a mesh whose border is Γ: the phase or
the paper's level set, then border closing), ``metrics`` (mass bound, areas, boundary error, UCD),
``render/`` (volume renders, cameras, image and video files) and ``plots`` (matplotlib pictures of meshes
and 2D currents). It reads currents duck-typed (``f``, ``evaluate``, ``alpha``, ``loops``) and imports no
model, data, app or experiment module."""

from deepcurrents.eval.meshing import MeshingResult, extract_curve_2d, extract_surface
from deepcurrents.eval.metrics import boundary_error, curve_length, mass_estimate, mass_to_area

__all__ = [
    "MeshingResult", "boundary_error", "curve_length", "extract_curve_2d", "extract_surface",
    "mass_estimate", "mass_to_area",
]
