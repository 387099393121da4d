"""Evaluation: meshing, metrics (mass bound, areas, boundary error), pictures."""

from deepcurrents.eval.meshing import MeshingResult, extract_curve_2d, extract_surface
from deepcurrents.eval.metrics import boundary_error, curve_length, mass_estimate, mass_to_area

__all__ = [
    "MeshingResult", "boundary_error", "curve_length", "extract_curve_2d", "extract_surface",
    "mass_estimate", "mass_to_area",
]
