"""Argument checks shared by the benchmark scripts (a helper, not a benchmark): an impossible value ends the script
with one sentence from ``argparse`` (status 2) before anything is measured, never a traceback or a nonsense number.

The scripts import it as a sibling (``sys.path.insert(0, <benchmarks/>)``), as family_time_to_quality.py imports
time_to_quality.py.
"""

from __future__ import annotations

import argparse
import math

import torch


def check_range(ap: argparse.ArgumentParser, flag: str, value, low: float, high: float | None = None, *,
                above: bool = False, below: bool = False, why: str = "") -> None:
    """``ap.error`` in one sentence unless ``value`` (a number, or every number of a list) is finite and ≥ ``low``
    (> ``low`` with ``above``) and, with ``high``, ≤ ``high`` (< ``high`` with ``below``); ``why`` is added to the
    sentence in parentheses. None (an option left unset) passes."""
    for v in value if isinstance(value, (list, tuple)) else [value]:
        if v is None:
            continue
        ok = math.isfinite(v) and (v > low if above else v >= low) and (
            high is None or (v < high if below else v <= high))
        if not ok:
            if high is not None:
                what = f"in {'(' if above else '['}{low:g}, {high:g}{')' if below else ']'}"
            else:
                what = f"greater than {low}" if above else f"at least {low}"
            ap.error(f"{flag} {v} must be {what}{f' ({why})' if why else ''}.")


def check_device(ap: argparse.ArgumentParser, name: str, flag: str = "--device") -> torch.device:
    """``name`` as a torch device this machine has, or ``ap.error`` in one sentence (a word that is no device, CUDA
    on a machine without it, a GPU index beyond the count). → torch.device."""
    try:
        device = torch.device(name)
    except (RuntimeError, ValueError):
        ap.error(f"{flag} {name!r} is not a device: give cpu, cuda or cuda:N.")
    if device.type not in ("cpu", "cuda"):
        ap.error(f"{flag} {name!r}: this benchmark runs on cpu or cuda (cuda:N).")
    if device.type == "cuda":
        if not torch.cuda.is_available():
            ap.error(f"{flag} {name} needs a CUDA GPU, and this machine has none ({flag} cpu runs anywhere).")
        if device.index is not None and device.index >= torch.cuda.device_count():
            ap.error(f"{flag} {name}: this machine has {torch.cuda.device_count()} CUDA GPU(s), numbered from 0.")
    return device
