"""Datasets and DataModules: ambient samples, targets, human-part data, augmentation."""

from deepcurrents.data.ambient import AmbientSamples, MinimalSurfaceDataModule, stream_seed

__all__ = ["AmbientSamples", "MinimalSurfaceDataModule", "stream_seed"]
