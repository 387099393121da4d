"""The family's window on f (``model.net.f_turns`` > 0; beyond the paper): f = W·tanh(h), h the decoder's output
and W = f_turns·J/2 with J = 4π·alpha_scale one full jump, so h is in units of the window (the first Adam steps move
h by about the learning rate; in f's own units one step would saturate it). A minimal current's f spans exactly one
J, so a window of two holds it with room while the phase cannot wind again along n (the dome the reconstruction
metric leaves free). Measurements: docs/notes/families.md, "A window on f"."""

from __future__ import annotations

import math

import torch


class FieldWindow:
    """f = W·tanh(h) for a window of ``turns`` full jumps 4π·``alpha_scale`` (turns 0: the identity)."""

    def __init__(self, turns: float, alpha_scale: float):
        self.turns, self.alpha_scale = float(turns), float(alpha_scale)

    @property
    def half_width(self) -> float:
        """W = turns·J/2, J = 4π·alpha_scale (0: no window)."""
        return self.turns * 2.0 * math.pi * self.alpha_scale

    def __call__(self, h: torch.Tensor,
                 grad_h: torch.Tensor | None = None) -> torch.Tensor | tuple[torch.Tensor, torch.Tensor]:
        """h (...,) → f; with grad_h (..., 3) also ∇f = W(1 − tanh²)·∇h."""
        w = self.half_width
        if w == 0:
            return h if grad_h is None else (h, grad_h)
        t = torch.tanh(h)
        return w * t if grad_h is None else (w * t, (w * (1 - t * t))[..., None] * grad_h)
