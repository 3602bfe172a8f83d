"""jaxapf: a JAX-accelerated, batched Monte-Carlo evaluator for artificial-potential-field obstacle
avoidance of UAVs with MPC tracking.

The engine (this namespace): fields of a scenario family (:func:`make_scenarios`) × settings of
gains (:class:`Gains`) → every registered metric, in one compiled call (:func:`evaluate`), or the
same as a table with a sweep's columns (:func:`evaluate_frame`); one episode's trajectory with
:func:`rollout`. The tools on top are subpackages: :mod:`jaxapf.sweep`,
:mod:`jaxapf.report`, :mod:`jaxapf.tune`, :mod:`jaxapf.simulate`, :mod:`jaxapf.bench`.

Extension points (``docs/extending.md``): planners and their weights ω, force terms, safety
filters, plants, sensing models, disturbances, scenario families and metrics, each a registry;
components declare their gains (:class:`GainSpec`), which become sweep keys, CLI flags and tunable
parameters.
"""

from .config import EpisodeConfig, MetricConfig, MPCConfig, PlannerConfig, SimConfig, VehicleConfig, WorldConfig
from .control import FILTERS, Passthrough, SafetyFilter, register_filter
from .datatypes import ObstacleColumns, Obstacles, Scenario, Trajectory
from .dynamics import (
    DISTURBANCES,
    PLANTS,
    Disturbance,
    DoubleIntegrator,
    Plant,
    Quadrotor,
    register_disturbance,
    register_plant,
)
from .frame import evaluate_frame
from .gains import GAINS, Gains, GainSpec, declare_gains, load_gains
from .metrics import METRICS, EpisodeContext, Metric, episode_metrics, register_metric
from .planners import APF, PLANNERS, WEIGHTS, ForceTerm, Planner, Weight, register_planner, register_weight
from .rollout import evaluate, rollout, rollout_metrics
from .scenarios import FAMILIES, FamilyParams, family_params, make_scenarios, register_family
from .sensing import SENSORS, Sensor, register_sensor
from .validation import BoundWarning, ConfigError

__all__ = [
    # the engine
    "rollout", "rollout_metrics", "evaluate", "evaluate_frame", "make_scenarios", "family_params", "episode_metrics",
    # configuration and data
    "Gains", "GainSpec", "load_gains", "SimConfig", "PlannerConfig", "VehicleConfig", "WorldConfig", "EpisodeConfig",
    "MetricConfig", "MPCConfig", "Scenario", "Obstacles", "ObstacleColumns", "Trajectory",
    # extension points
    "Planner", "APF", "Weight", "ForceTerm", "SafetyFilter", "Passthrough", "Plant", "DoubleIntegrator", "Quadrotor",
    "Sensor", "Disturbance", "FamilyParams", "Metric", "EpisodeContext",
    "register_planner", "register_weight", "register_filter", "register_plant", "register_sensor",
    "register_disturbance", "register_family", "register_metric", "declare_gains",
    "PLANNERS", "WEIGHTS", "FILTERS", "PLANTS", "SENSORS", "DISTURBANCES", "FAMILIES", "METRICS", "GAINS",
    # errors
    "ConfigError", "BoundWarning",
]
