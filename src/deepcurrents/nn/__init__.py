"""Neural modules: Fourier features, the field MLP, the current (the paper's, and its builder with extensions)."""

from deepcurrents.nn.builder import neural_current
from deepcurrents.nn.current import NeuralCurrent, spatial_gradient
from deepcurrents.nn.fourier import FourierFeatures
from deepcurrents.nn.mlp import FieldMLP

__all__ = ["FieldMLP", "FourierFeatures", "NeuralCurrent", "neural_current", "spatial_gradient"]
