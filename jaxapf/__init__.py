"""jaxapf: a JAX-accelerated, batched Monte-Carlo evaluator for artificial-potential-field obstacle
avoidance of UAVs with MPC tracking.

The engine (this namespace): fields of a scenario family (:func:`make_scenarios`) × settings of
gains (:class:`Gains`) → every registered metric, in one compiled call (:func:`evaluate`), or the
same as a table with a sweep's columns (:func:`evaluate_frame`); one episode's trajectory with
:func:`rollout`. The tools on top are subpackages: :mod:`jaxapf.sweep`,
:mod:`jaxapf.report`, :mod:`jaxapf.tune`, :mod:`jaxapf.simulate`, :mod:`jaxapf.bench`.

Extension points (``docs/extending.md``): planners and their weights ω, force terms, safety
filters, disturbance estimators, plants, sensing models, disturbances, scenario families and
metrics, each a registry;
components declare their gains (:class:`GainSpec`), which become sweep keys, CLI flags and tunable
parameters.
"""

import os
from importlib import import_module

# drone-models (the crazyflie plants, jaxapf.world.crazyflie) loads only into a process whose SciPy was
# imported with its array API switched on; set before anything imports SciPy.
os.environ.setdefault("SCIPY_ARRAY_API", "1")

#: public name -> the module it lives in, imported on first use (PEP 562): ``import jaxapf`` and the
#: command line's help, list and argument errors import no JAX
_LAZY = {
    "EpisodeConfig": ".config", "MetricConfig": ".config", "MPCConfig": ".config", "PlannerConfig": ".config",
    "SimConfig": ".config", "VehicleConfig": ".config", "WorldConfig": ".config",
    "FILTERS": ".control", "Passthrough": ".control", "SafetyFilter": ".control", "register_filter": ".control",
    "ESTIMATORS": ".control", "Estimator": ".control", "register_estimator": ".control",
    "ObstacleColumns": ".datatypes", "Obstacles": ".datatypes", "Scenario": ".datatypes", "Trajectory": ".datatypes",
    "DISTURBANCES": ".world", "PLANTS": ".world", "Disturbance": ".world", "DoubleIntegrator": ".world",
    "Plant": ".world", "Quadrotor": ".world", "register_disturbance": ".world", "register_plant": ".world",
    "SENSORS": ".world", "Sensor": ".world", "register_sensor": ".world",
    "evaluate_frame": ".sweep",
    "GAINS": ".gains", "Gains": ".gains", "GainSpec": ".gains", "declare_gains": ".gains", "load_gains": ".gains",
    "METRICS": ".metrics", "EpisodeContext": ".metrics", "Metric": ".metrics", "episode_metrics": ".metrics",
    "register_metric": ".metrics",
    "APF": ".planners", "PLANNERS": ".planners", "ForceTerm": ".planners",
    "Planner": ".planners", "Weight": ".planners", "register_planner": ".planners",
    "evaluate": ".engine", "rollout": ".engine", "rollout_metrics": ".engine",
    "FAMILIES": ".scenarios", "FamilyParams": ".scenarios", "family_params": ".scenarios",
    "make_scenarios": ".scenarios", "register_family": ".scenarios",
    "BoundWarning": ".validation", "ConfigError": ".validation",
}

__all__ = list(_LAZY)


def __getattr__(name: str):
    """The first public name imports the whole engine, as ``import jaxapf`` did before it was lazy: the
    registries (gains, planners, metrics, ...) fill as their modules are imported, so ``jaxapf.Gains``
    must find every component's gains declared."""
    if name not in _LAZY:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    modules = {module: import_module(module, __name__) for module in dict.fromkeys(_LAZY.values())}
    globals().update({public: getattr(modules[module], public) for public, module in _LAZY.items()})
    return globals()[name]


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
