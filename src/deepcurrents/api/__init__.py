"""The Python API: DeepCurrents from a notebook or a pipeline, on the command line's code path.

>>> import numpy as np, deepcurrents as dc
>>> t = np.linspace(0, 2 * np.pi, 200, endpoint=False)
>>> result = dc.minimal_surface(np.stack([np.cos(t), np.sin(t), 0.3 * np.cos(2 * t)], 1))   # doctest: +SKIP
>>> result.mesh()                                                                            # doctest: +SKIP

`minimal_surface` and `reconstruct` train (the same configs and runner as ``python train.py``),
`train` runs any experiment (a suite too), `load` opens any checkpoint; each gives a `Result`
(a `FamilyResult` for a family). Mistakes raise `deepcurrents.errors.UserInputError` with one
sentence, before anything trains.
"""

from deepcurrents.api.results import FamilyResult, Result
from deepcurrents.api.runs import load, minimal_surface, reconstruct
from deepcurrents.api.runs import train_experiment as train
from deepcurrents.errors import ConfigError, UserInputError
from deepcurrents.models.loading import CheckpointError

__all__ = ["CheckpointError", "ConfigError", "FamilyResult", "Result", "UserInputError", "load", "minimal_surface",
           "reconstruct", "train"]
