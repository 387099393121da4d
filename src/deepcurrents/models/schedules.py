"""Learning-rate schedules that follow a run's budget: steps, wall-clock seconds, or whichever ends first.

The authors' schedule (lr × gamma every step_size steps) knows only steps. With a wall-clock budget
(``trainer.max_time``) a step schedule either never decays (the budget ends first) or decays too early, so
``model.optim.schedule=cosine`` makes the horizon the budget: progress p = max(step / max_steps,
elapsed / max_time) ∈ [0, 1], a linear warm-up over the first ``warmup`` of p, then a cosine from 1 down
to ``min_factor``.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import torch

from deepcurrents.errors import ConfigError

SCHEDULES = ("step", "cosine")
# the model.optim settings each schedule reads, and those it leaves unread
SCHEDULE_KEYS = {"step": ("step_size", "gamma"), "cosine": ("warmup", "min_factor")}


def budget_progress(step: int, max_steps: int | None, elapsed: float, max_seconds: float | None) -> float:
    """Fraction of the budget used: the larger of the step and time fractions, clipped to [0, 1].

    ``max_steps`` None or ≤ 0 means no step limit, ``max_seconds`` None no time limit; with neither there is
    no horizon and this raises ConfigError.
    """
    fractions = []
    if max_steps is not None and max_steps > 0:
        fractions.append(step / max_steps)
    if max_seconds is not None and max_seconds > 0:
        fractions.append(elapsed / max_seconds)
    if not fractions:
        raise ConfigError("model.optim.schedule=cosine needs a horizon: set trainer.max_steps or trainer.max_time.")
    return min(max(max(fractions), 0.0), 1.0)


def cosine_factor(progress: float, warmup: float = 0.0, min_factor: float = 0.0) -> float:
    """lr multiplier at ``progress`` ∈ [0, 1]: linear warm-up to 1 over [0, warmup], then a half cosine
    from 1 to ``min_factor`` over [warmup, 1]."""
    if warmup > 0 and progress < warmup:
        return max(progress / warmup, 1e-3)  # never exactly zero: the first step still moves
    span = max(1.0 - warmup, 1e-12)
    t = min(max((progress - warmup) / span, 0.0), 1.0)
    return min_factor + (1.0 - min_factor) * 0.5 * (1.0 + math.cos(math.pi * t))


class BudgetCosine(torch.optim.lr_scheduler.LambdaLR):
    """LambdaLR whose factor is ``cosine_factor(progress_fn())``: the scheduler is stepped every optimiser
    step, but the factor comes from the budget used so far (steps and/or seconds), not the step count."""

    def __init__(self, optimizer: torch.optim.Optimizer, progress_fn: Callable[[], float], warmup: float = 0.0,
                 min_factor: float = 0.0):
        self.progress_fn = progress_fn
        super().__init__(optimizer, lambda _: cosine_factor(progress_fn(), warmup, min_factor))

    def state_dict(self) -> dict:
        """Without the progress function (a closure over the trainer: not picklable, rebuilt on resume)."""
        return {k: v for k, v in super().state_dict().items() if k != "progress_fn"}


def trainer_progress(trainer, step: int, elapsed: float | None = None) -> float:
    """``budget_progress`` of a Lightning trainer: its max_steps and the duration of its Timer callback
    (which ``trainer.max_time`` installs). ``elapsed`` defaults to the Timer's training time."""
    from lightning.pytorch.callbacks import Timer
    from lightning.pytorch.trainer.states import RunningStage

    max_seconds = None
    timer = next((cb for cb in trainer.callbacks if isinstance(cb, Timer)), None)
    if timer is not None:
        used = timer.time_elapsed(RunningStage.TRAINING)
        remaining = timer.time_remaining(RunningStage.TRAINING)
        if remaining is not None:
            max_seconds = used + remaining
        if elapsed is None:
            elapsed = used
    return budget_progress(step, trainer.max_steps, elapsed or 0.0, max_seconds)
