"""Where a current lives: evaluation puts its sample points on the current's device."""

from __future__ import annotations

import os
from pathlib import Path

import torch


def device_of(module) -> torch.device:
    """The device of a module's first parameter; the CPU for a module without parameters (or no module)."""
    try:
        return next(module.parameters()).device
    except (StopIteration, AttributeError):
        return torch.device("cpu")


def available_memory() -> int | None:
    """Bytes of memory a new allocation can have without swapping: Linux's MemAvailable (free memory and
    reclaimable caches), capped by the process's cgroup limit (a container's ``--memory``, cgroup v2) when it has
    one; elsewhere the machine's physical memory (sysconf); None where neither can be read (no check relies on it)."""
    free = None
    try:
        with open("/proc/meminfo") as meminfo:
            for line in meminfo:
                if line.startswith("MemAvailable:"):
                    free = int(line.split()[1]) * 1024
                    break
    except (OSError, ValueError, IndexError):
        pass
    if free is None:
        try:
            free = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
        except (AttributeError, ValueError, OSError):
            return None
    try:  # cgroup v2: the limit and what the group already uses
        root = Path("/sys/fs/cgroup")
        limit = (root / "memory.max").read_text().strip()
        if limit != "max":
            free = min(free, int(limit) - int((root / "memory.current").read_text().strip()))
    except (OSError, ValueError):
        pass
    return free
