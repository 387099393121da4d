"""Neural modules: Fourier features, the field MLP, the current."""

from deepcurrents.nn.current import NeuralCurrent, spatial_gradient
from deepcurrents.nn.fourier import FourierFeatures
from deepcurrents.nn.mlp import FieldMLP

__all__ = ["FieldMLP", "FourierFeatures", "NeuralCurrent", "spatial_gradient"]
