"""Pure tensor geometry: Biot–Savart fields, boundary curves, mesh utilities. No networks here."""

from deepcurrents.geometry.biot_savart import angle_2d, biot_savart, biot_savart_2d, loop_segments, solid_angle
from deepcurrents.geometry.curves import (
    NAMED_CURVES,
    Boundary,
    BoundaryError,
    PointBoundary,
    borromean_rings,
    circle,
    hopf_link,
    load_boundary,
    polyline_length,
    read_curve_file,
    trefoil,
    validate_loops,
    validate_points,
)

__all__ = [
    "angle_2d",
    "NAMED_CURVES", "Boundary", "BoundaryError", "PointBoundary", "biot_savart", "biot_savart_2d",
    "borromean_rings", "circle", "hopf_link", "load_boundary", "loop_segments", "polyline_length",
    "read_curve_file", "solid_angle", "trefoil", "validate_loops", "validate_points",
]
