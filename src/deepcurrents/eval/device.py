"""Where a current lives: evaluation puts its sample points on the current's device."""

from __future__ import annotations

import os
from pathlib import Path

import torch

from deepcurrents.errors import ConfigError


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


def require_memory(setting: str, need: int, what: str = "") -> None:
    """ConfigError when ``need`` bytes cannot fit in the memory available here (:func:`available_memory`; no check
    where it cannot be read): "<setting> asks for <what>about N GiB of memory, but M GiB are available here; lower
    it." ``setting`` is the key and value (``model.grid.resolution=5000``), ``what`` what it asks for (``a
    100001×100001 grid, ``), so a size that cannot fit is one sentence before the allocation fails."""
    free = available_memory()
    if free is not None and need > free:
        raise ConfigError(f"{setting} asks for {what}about {need / 2**30:.1f} GiB of memory, but "
                          f"{free / 2**30:.1f} GiB are available here; lower it.")

