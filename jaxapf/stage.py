"""What the closed loop's stateful stages share: declared gains, a state through the episode, a registry.

A safety filter (:mod:`jaxapf.control.filters`), a sensing model (:mod:`jaxapf.world.sensing`) and a
disturbance (:mod:`jaxapf.world.wind`) are each a :class:`Stage`: a frozen dataclass that declares
the gains it reads and makes its state at the start of an episode with :meth:`Stage.init` (optax's
``init``; each kind adds its own call). Registering a stage in its kind's registry declares its
gains, as for every component.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, ClassVar

from .gains import GainSpec, declare_entry_gains
from .metrics import register_entry_metrics

if TYPE_CHECKING:
    from .config import SimConfig
    from .datatypes import Scenario
    from .gains import Gains

__all__ = ["Stage", "DECLARE"]

#: What a component registry does with every new entry (``Registry(on_register=DECLARE)``): declare the
#: gains it reads and register the metrics it owns.
DECLARE = (declare_entry_gains, register_entry_metrics)


class Stage:
    """A stateful stage of the closed loop. Subclasses are frozen dataclasses.

    Attributes:
      gains: the gains it reads (declared when it is registered).
      metrics: the metrics of what only it records (registered with it), e.g. a filter's infeasible steps.
    """

    gains: ClassVar[tuple[GainSpec, ...]] = ()
    metrics: ClassVar[tuple] = ()

    def init(self, scenario: "Scenario", gains: "Gains", sim: "SimConfig") -> Any:
        """The stage's state at the start of an episode (default: none)."""
        return ()
