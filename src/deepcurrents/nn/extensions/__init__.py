"""Pieces beyond the paper that compose into a ``NeuralCurrent`` (``extensions=``), each chosen in config.

An extension keeps its state in buffers of the current it is attached to (``attach``), under fixed names, so that
checkpoints keep their keys; it may give f an output basis in Γ's angle u (``output_basis``: phase harmonics),
transform (f, ω) after the network (``transform``: phase sharpening), open during training (``set_progress``) and
change how meshers read the current (``level_set_view``). ``CurrentExtension`` does nothing for each."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import AbstractContextManager, ExitStack, contextmanager, nullcontext

import torch

# an extension that opens during training ramps in linearly over this fraction of the budget
RAMP = 0.2


def opened(progress: float, start: float) -> float:
    """How far an extension that starts at the fraction ``start`` of the budget is open at ``progress``: 0 before,
    then linear to 1 over ``RAMP``."""
    return min(max((progress - start) / RAMP, 0.0), 1.0)


class CurrentExtension:
    """The hooks a ``NeuralCurrent`` calls; each default leaves the paper's current as it is."""

    outputs: int = 0  # MLP outputs beyond f's one that it reads

    def attach(self, current: torch.nn.Module) -> None:
        """Registers the extension's buffers on ``current``."""

    def read_state(self, current: torch.nn.Module) -> None:
        """Reads Python copies of its buffers (after construction and after a checkpoint loads)."""

    @property
    def needs_angle(self) -> bool:
        """Whether it needs Γ's angle u now (``NeuralCurrent.boundary_angle``)."""
        return False

    @property
    def follows_progress(self) -> bool:
        """Whether training must call ``set_progress``."""
        return False

    def set_progress(self, current: torch.nn.Module, progress: float) -> None:
        """Its state at the fraction ``progress`` ∈ [0, 1] of the training budget."""

    def output_basis(self, current: torch.nn.Module, x: torch.Tensor, u: torch.Tensor | None) -> tuple | None:
        """(e, ∂e/∂u), each (N, M), for an MLP with M outputs, f = Σ_m e_m h_m; None: not this extension's."""
        return None

    def transform(self, current: torch.nn.Module, f: torch.Tensor, omega: torch.Tensor | None,
                  u: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor | None]:
        """(f, ω) after the network; ω may be None (f alone). f (N,), ω (N, d), u (N,) or None."""
        return f, omega

    def level_set_view(self, current: torch.nn.Module) -> AbstractContextManager:
        """A context in which the meshers read the current's level sets."""
        return nullcontext()


class ExtensionHost:
    """What a current does with its ``extensions`` (a tuple of ``CurrentExtension``): the hooks' plumbing."""

    extensions: tuple = ()

    def attach_extensions(self, extensions) -> None:
        """Keeps ``extensions`` and lets each register its buffers on this current."""
        self.extensions = tuple(extensions)
        for extension in self.extensions:
            extension.attach(self)

    def read_extensions(self) -> None:
        """Each extension's Python copies of its buffers (after construction and after a checkpoint loads)."""
        for extension in self.extensions:
            extension.read_state(self)

    @property
    def needs_angle(self) -> bool:
        """Whether an extension needs Γ's angle u now."""
        return any(extension.needs_angle for extension in self.extensions)

    def output_basis(self, x: torch.Tensor, u: torch.Tensor | None) -> tuple | None:
        """(e, ∂e/∂u) of an MLP with several outputs, f = Σ_m e_m h_m (an extension's), or None: f = h."""
        return next((b for e in self.extensions if (b := e.output_basis(self, x, u)) is not None), None)

    @property
    def follows_progress(self) -> bool:
        """Whether training must call ``set_progress`` (an extension that opens during training)."""
        return any(extension.follows_progress for extension in self.extensions)

    def set_progress(self, progress: float) -> None:
        """The extensions at the fraction ``progress`` ∈ [0, 1] of the training budget."""
        for extension in self.extensions:
            extension.set_progress(self, progress)

    @contextmanager
    def level_set_view(self) -> Iterator:
        """This current as the meshers read its level sets (a sharpening off: ``nn.extensions.sharpening``)."""
        with ExitStack() as stack:
            for extension in self.extensions:
                stack.enter_context(extension.level_set_view(self))
            yield self
