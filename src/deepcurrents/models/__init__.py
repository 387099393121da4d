"""LightningModules: single currents (minimal surfaces, reconstruction), families, baselines."""

from deepcurrents.models.base import CHECKPOINT_KEY, DeepCurrentsModule
from deepcurrents.models.current_module import CurrentModule, boundary_spec

__all__ = ["CHECKPOINT_KEY", "CurrentModule", "DeepCurrentsModule", "boundary_spec"]
