"""User-facing errors: each carries one sentence naming the input and what is wrong with it."""

from __future__ import annotations

import math
from typing import Any


class UserInputError(ValueError):
    """Bad input from the user (file, curve, config value). The entry points print it without a traceback."""


class ConfigError(UserInputError):
    """An impossible configuration value."""


class NonFiniteLossError(RuntimeError):
    """The loss became NaN or infinite during training."""


def positive_int(name: str, value: Any, minimum: int = 1) -> int:
    """``value`` as an int ≥ ``minimum``, or ConfigError naming the setting ``name`` (e.g. ``data.num_samples``).
    Booleans and floats are refused: ``steps=2.5`` and ``steps=true`` are mistakes, not counts."""
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        what = "a positive integer" if minimum == 1 else f"an integer ≥ {minimum}"
        raise ConfigError(f"{name}={value!r} must be {what}.")
    return value


def number_at_least(name: str, value: Any, minimum: float = 0.0, strict: bool = False) -> float:
    """``value`` as a finite float ≥ ``minimum`` (> with ``strict``), or ConfigError naming the setting ``name``.
    A string or a boolean is refused in the same sentence (``not value >= 0`` would raise a raw TypeError)."""
    number = not isinstance(value, bool) and isinstance(value, (int, float))
    ok = number and math.isfinite(value) and (value > minimum if strict else value >= minimum)
    if not ok:
        if minimum == 0:  # a word is told it is not a number at all (lr=fast "must be positive" read oddly)
            what = ("positive" if strict else "non-negative") if number else \
                f"a {'positive' if strict else 'non-negative'} number"
        else:
            what = f"a finite number {'>' if strict else '≥'} {minimum:g}"
        raise ConfigError(f"{name}={value} must be {what}.")
    return float(value)


def number_between(name: str, value: Any, low: float, high: float) -> float:
    """``value`` as a float in [``low``, ``high``], or ConfigError naming the setting ``name`` (a string or a boolean
    in the same sentence)."""
    ok = not isinstance(value, bool) and isinstance(value, (int, float)) and low <= value <= high
    if not ok:
        raise ConfigError(f"{name}={value} must be in [{low:g}, {high:g}].")
    return float(value)


def share(name: str, value: Any, why: str = "") -> float:
    """``value`` as a float in (0, 1] (a share of a batch), or ConfigError naming the setting ``name``; ``why``
    is added to the sentence. A string or a boolean is refused in the same sentence."""
    ok = not isinstance(value, bool) and isinstance(value, (int, float)) and 0.0 < value <= 1.0
    if not ok:
        raise ConfigError(f"{name}={value} must be in (0, 1]{f' ({why})' if why else ''}.")
    return float(value)
