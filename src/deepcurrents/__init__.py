"""DeepCurrents: neural currents ω = ∇f_θ + α_Γ for surfaces with boundary.

``deepcurrents.minimal_surface``, ``reconstruct``, ``train``, ``load`` and the results they give are the Python API
(``deepcurrents.api``), loaded on first use so that ``import deepcurrents`` stays light.
"""

from deepcurrents.errors import ConfigError, UserInputError

__version__ = "0.1.0"

_API = ("minimal_surface", "reconstruct", "train", "load", "Result", "FamilyResult", "CheckpointError")
__all__ = [*_API, "ConfigError", "UserInputError", "__version__"]


def __getattr__(name: str):
    if name in _API:
        from deepcurrents import api

        return getattr(api, name)
    raise AttributeError(f"module 'deepcurrents' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_API))
