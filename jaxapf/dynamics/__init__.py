"""Plants and disturbances: the vehicle models the closed loop integrates (SPEC 1) and what acts on
them besides the command, as registered components."""

from .base import PLANTS, Plant, register_plant
from .double_integrator import DoubleIntegrator, discrete_matrices, step
from .quadrotor import HUMMINGBIRD, Quadrotor, QuadrotorState, Vehicle
from .wind import DISTURBANCES, Calm, Disturbance, Wind, register_disturbance

__all__ = ["Plant", "PLANTS", "register_plant", "DoubleIntegrator", "discrete_matrices", "step", "Quadrotor",
           "QuadrotorState", "Vehicle", "HUMMINGBIRD", "Disturbance", "DISTURBANCES", "register_disturbance", "Calm",
           "Wind"]
