"""Reading a current for its level sets: a sharpened current (``nn.extensions.sharpening``) through
its network's own phase, whose level sets are the same (ψ is monotone) and which is smooth where ψ∘φ is steep."""

from __future__ import annotations

import functools
from collections.abc import Callable
from contextlib import AbstractContextManager, nullcontext

from torch import nn


def level_set_view(current: nn.Module) -> AbstractContextManager:
    """A context in which ``current`` is read for its level sets: a current with ``level_set_view`` (a
    ``NeuralCurrent`` and its extensions) as that says; any other current as it is."""
    view = getattr(current, "level_set_view", None)
    return view() if view is not None else nullcontext()


def reads_level_sets(extract: Callable) -> Callable:
    """Decorates ``extract(current, ...)`` (a mesher) to run inside ``level_set_view(current)``."""
    @functools.wraps(extract)
    def wrapper(current, *args, **kwargs):
        with level_set_view(current):
            return extract(current, *args, **kwargs)
    return wrapper
