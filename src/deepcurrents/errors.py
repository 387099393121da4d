"""User-facing errors: each carries one sentence naming the input and what is wrong with it."""

from __future__ import annotations

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
