"""The world the vehicle flies in: the plants the closed loop integrates (SPEC 1), the disturbances
acting on them besides the command, and the sensing models through which the stack sees the UAV and
the obstacles, as registered components."""

from .base import PLANTS, Plant, register_plant
from .crazyflie import FIDELITIES, Crazyflie, CrazyflieState
from .double_integrator import DoubleIntegrator, discrete_matrices, step
from .quadrotor import HUMMINGBIRD, Quadrotor, QuadrotorState, Vehicle
from .sensing import SENSORS, Ideal, NoisySensor, Sensor, register_sensor
from .wind import DISTURBANCES, Calm, Disturbance, Wind, register_disturbance

__all__ = ["Plant", "PLANTS", "register_plant", "DoubleIntegrator", "discrete_matrices", "step", "Quadrotor",
           "QuadrotorState", "Vehicle", "HUMMINGBIRD", "Disturbance", "DISTURBANCES", "register_disturbance", "Calm",
           "Wind", "Sensor", "Ideal", "NoisySensor", "SENSORS", "register_sensor", "Crazyflie",
           "CrazyflieState", "FIDELITIES"]
