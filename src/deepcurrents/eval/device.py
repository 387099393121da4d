"""Where a current lives: evaluation puts its sample points on the current's device."""

from __future__ import annotations

import torch


def device_of(module) -> torch.device:
    """The device of a module's first parameter; the CPU for a module without parameters (or no module)."""
    try:
        return next(module.parameters()).device
    except (StopIteration, AttributeError):
        return torch.device("cpu")


def available_memory() -> int | None:
    """Bytes of memory this machine can give a new allocation without swapping (Linux's MemAvailable: free memory
    and reclaimable caches); None where it cannot be read (then no check relies on it)."""
    try:
        with open("/proc/meminfo") as meminfo:
            for line in meminfo:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None
