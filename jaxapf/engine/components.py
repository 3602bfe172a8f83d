"""The components a simulation setting names: one static key and one registry each.

================  ==========================================  =====================================
key               registry                                    what it is
================  ==========================================  =====================================
``method``        :data:`jaxapf.planners.PLANNERS`            the planner (reference for the MPC)
``filter``        :data:`jaxapf.control.FILTERS`              the safety filter after the MPC
``plant``         :data:`jaxapf.world.PLANTS`                 the vehicle model integrated
``sensor``        :data:`jaxapf.world.SENSORS`                what the stack sees of the world
``disturbance``   :data:`jaxapf.world.DISTURBANCES`           what acts on the plant besides the command
``estimator``     :data:`jaxapf.control.ESTIMATORS`           the disturbance the MPC plans with
================  ==========================================  =====================================

Every tool reads this table (which gains a setting reads, which names a spec may give, what
``jaxapf list`` shows), so a new kind of component is one row here.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Mapping

from ..control import ESTIMATORS, FILTERS, MPC_GAINS
from ..planners import PLANNERS
from ..planners.apf import FUSED, fused
from ..registry import Registry
from ..world import DISTURBANCES, PLANTS
from ..world.sensing import SENSORS

if TYPE_CHECKING:
    from ..config import SimConfig

__all__ = ["COMPONENTS", "component", "components_read_gains", "component_names", "gains_read", "metrics_in_use"]

#: Static key of a simulation setting -> the registry of the components it names.
COMPONENTS: Mapping[str, Registry[Any]] = {"method": PLANNERS, "filter": FILTERS, "plant": PLANTS,
                                           "sensor": SENSORS, "disturbance": DISTURBANCES, "estimator": ESTIMATORS}


def component(key: str, name: str, where: str = "sim") -> Any:
    """The component ``name`` of :data:`COMPONENTS` ``key``; a method holding :data:`~jaxapf.planners.apf.FUSED` is a
    fused program's planner (:func:`~jaxapf.planners.apf.fused`). An unknown name raises
    :class:`~jaxapf.validation.ConfigError` naming ``where.key``."""
    if key == "method" and FUSED in name:
        return fused(name)
    return COMPONENTS[key].get(name, f"{where}.{key}")


def components_read_gains(names: Mapping[str, str], where: str = "sim") -> frozenset[str]:
    """The gains the components ``names`` (``{key: name}`` for every key of :data:`COMPONENTS`)
    declare (:func:`component`)."""
    return frozenset(g.name for key in COMPONENTS for g in component(key, names[key], where).gains)


def component_names(sim: SimConfig) -> dict[str, str]:
    """``{key: name}`` of the components ``sim`` names (:data:`COMPONENTS`)."""
    flat = sim.flat()
    return {key: flat[key] for key in COMPONENTS}


def gains_read(sim: SimConfig) -> frozenset[str]:
    """The gains a :func:`~jaxapf.engine.rollout` with ``sim`` reads: those its planner, safety filter, plant, sensor,
    disturbance and estimator declare, and the MPC's weight scales with ``sim.mpc_weights = "gains"``. Settings
    that agree on these fly the same episodes (a sweep runs them once)."""
    read = components_read_gains(component_names(sim))
    return read | {g.name for g in MPC_GAINS} if sim.planner.mpc_weights == "gains" else read


def metrics_in_use(sim: SimConfig, names: tuple[str, ...]) -> tuple[str, ...]:
    """The metrics of ``names`` that measure something ``sim`` flies: those no component owns, and those the
    named components own (a filter's infeasible steps only where that filter flies; ``entry.metrics``)."""
    named = component_names(sim)
    owners: dict[str, set[tuple[str, str]]] = {}
    for key, registry in COMPONENTS.items():
        for name, entry in registry.items():
            for m in getattr(entry, "metrics", ()):
                owners.setdefault(m.name, set()).add((key, name))
    return tuple(n for n in names if n not in owners or any(named[k] == c for k, c in owners[n]))
