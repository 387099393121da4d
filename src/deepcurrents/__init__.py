"""DeepCurrents: neural currents ω = ∇f_θ + α_Γ for surfaces with boundary."""

__version__ = "0.1.0"
