"""Where a current lives: evaluation puts its sample points on the current's device."""

from __future__ import annotations

import torch


def device_of(module) -> torch.device:
    """The device of a module's first parameter; the CPU for a module without parameters (or no module)."""
    try:
        return next(module.parameters()).device
    except (StopIteration, AttributeError):
        return torch.device("cpu")
