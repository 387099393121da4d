"""The benchmark's curves with exact minimal areas (benchmarks/time_to_quality.py), against independent truth."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
from scipy.integrate import quad

from deepcurrents.geometry import load_boundary

ROOT = Path(__file__).resolve().parents[1]


def _benchmark():
    spec = importlib.util.spec_from_file_location("time_to_quality", ROOT / "benchmarks" / "time_to_quality.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_catenoid_area_is_the_surface_of_revolution_integral(tmp_path):
    ttq = _benchmark()
    c = ttq.catenoid_neck(0.5, 0.2)
    assert abs(c * math.cosh(0.2 / c) - 0.5) < 1e-12
    assert c > 0.2 / 1.19967864  # the stable (outer) catenoid, not the inner one
    # area = ∫ 2π r √(1 + r'²) dz for r = c cosh(z/c), by quadrature
    area, _ = quad(lambda z: 2 * math.pi * c * math.cosh(z / c) * math.sqrt(1 + math.sinh(z / c) ** 2), -0.2, 0.2)
    path, exact = ttq.curves(tmp_path)["catenoid"]
    assert abs(exact - area) < 1e-9
    assert exact < 2 * math.pi * 0.25  # below the two disks: the catenoid is the minimum
    top, bottom = load_boundary(path, normalize=False).loops
    vector_area = [0.5 * np.cross(lp, np.roll(lp, -1, 0)).sum(0) for lp in (top, bottom)]
    assert vector_area[0][2] > 0 > vector_area[1][2]  # opposite orientations: ∂ of the catenoid
    assert np.allclose(top[:, 2], 0.2) and np.allclose(bottom[:, 2], -0.2)
