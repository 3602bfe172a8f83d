"""Plants: the vehicle models the closed loop integrates (SPEC 1), as registered components."""

from .base import PLANTS, Plant, register_plant
from .double_integrator import DoubleIntegrator, discrete_matrices, step

__all__ = ["Plant", "PLANTS", "register_plant", "DoubleIntegrator", "discrete_matrices", "step"]
