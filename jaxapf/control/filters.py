"""Safety filters: the last word between the MPC's acceleration and the plant.

A :class:`SafetyFilter` maps the MPC's first acceleration to the one the plant receives, every
control step, with a state it may carry through the episode (an optax-like ``init`` and a call).
It declares the gains it reads and reports per-step diagnostics (each becomes an entry of
:attr:`~jaxapf.datatypes.Trajectory.extras`, which metrics may read). ``none``
(:class:`Passthrough`) applies the MPC's acceleration as it is, the paper's stack.

Register one with :func:`register_filter`; ``filter = NAME`` in a sweep spec then places it on top
of any planner (``docs/extending.md``).
"""

from __future__ import annotations

import abc
import dataclasses
from typing import TYPE_CHECKING, Any

from jax import Array

from ..registry import Registry
from ..stage import DECLARE, Stage

if TYPE_CHECKING:
    from ..config import SimConfig
    from ..datatypes import ObstacleColumns
    from ..gains import Gains

__all__ = ["SafetyFilter", "Passthrough", "FILTERS", "register_filter"]


class SafetyFilter(Stage, abc.ABC):
    """Maps the MPC's acceleration to the applied one (a :class:`~jaxapf.stage.Stage`: gains, ``init``)."""

    @abc.abstractmethod
    def __call__(self, state: Any, accel: Array, x: Array, t: Array, obstacles: "ObstacleColumns", gains: "Gains",
                 sim: "SimConfig") -> tuple[Array, Any, dict[str, Array]]:
        """``(applied acceleration (3,), next state, diagnostics)`` for the MPC's ``accel`` (3,) at the
        state ``x = [p, v]`` (6,) and time ``t`` (obstacles at ``t = 0``, component-first)."""


@dataclasses.dataclass(frozen=True)
class Passthrough(SafetyFilter):
    """No filter: the MPC's acceleration is applied as it is (the paper's stack)."""

    def __call__(self, state: Any, accel: Array, x: Array, t: Array, obstacles: Any, gains: Any,
                 sim: Any) -> tuple[Array, Any, dict[str, Array]]:
        return accel, state, {}


#: Registered safety filters: the values of ``filter`` (default ``none``).
FILTERS: Registry[SafetyFilter] = Registry("safety filter", on_register=DECLARE, listed_as="filters",
                                            role="safety filter between the MPC and the plant")


def register_filter(name: str, safety_filter: SafetyFilter, *, replace: bool = False) -> SafetyFilter:
    """Register ``safety_filter`` as ``filter = name`` (its gains are declared)."""
    return FILTERS.register(name, safety_filter, replace=replace)


register_filter("none", Passthrough())
