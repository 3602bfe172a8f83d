"""The plant protocol: the vehicle model a closed loop integrates, and its registry.

A :class:`Plant` owns its state layout (any pytree of arrays), integrates one control step from the
applied acceleration command, reports the UAV's position and velocity (what the metrics and the
MPC see), and names the linear model the MPC plans with. The double integrator
(:class:`~jaxapf.world.double_integrator.DoubleIntegrator`, paper eq. 4–7) is the default and is
exactly the MPC's own model; a plant with more physics (e.g. a quadrotor, paper eq. 1–3) keeps the
MPC planning with the double integrator and differs from it only in how the command is realised.

Register one with :func:`register_plant`; ``plant = NAME`` in a sweep spec then selects it
(``docs/extending.md``).
"""

from __future__ import annotations

import abc
from typing import TYPE_CHECKING, Any, ClassVar

from jax import Array

from ..gains import GainSpec
from ..registry import Registry
from ..stage import DECLARE

if TYPE_CHECKING:
    from ..config import SimConfig
    from ..gains import Gains

__all__ = ["Plant", "PLANTS", "register_plant"]


class Plant(abc.ABC):
    """A vehicle model. Subclasses are frozen dataclasses (hashable: they are static configuration).

    Attributes:
      gains: the traced parameters the plant reads (declared when it is registered).
      metrics: the metrics of what only it records (registered with it), e.g. a quadrotor's tilt.
    """

    gains: ClassVar[tuple[GainSpec, ...]] = ()
    metrics: ClassVar[tuple] = ()

    @abc.abstractmethod
    def init(self, start: Array, gains: "Gains", sim: "SimConfig") -> Any:
        """The state at rest at ``start`` (3,)."""

    @abc.abstractmethod
    def kinematics(self, state: Any) -> Array:
        """``[p, v]`` (6,) in the world frame: what the MPC plans from and the metrics record."""

    @abc.abstractmethod
    def step(self, state: Any, accel: Array, disturbance: Array, gains: "Gains", sim: "SimConfig"
             ) -> tuple[Any, dict[str, Array]]:
        """The state one control step ``sim.episode.dt`` later under the acceleration command
        ``accel`` (3,) and the ``disturbance`` (3,), an acceleration [m/s²] in the world frame held
        over the step (:mod:`jaxapf.world.wind`; zeros in a calm world), and the step's
        diagnostics (``{}`` if none; each becomes a per-step entry of
        :attr:`~jaxapf.datatypes.Trajectory.extras`)."""

    @abc.abstractmethod
    def linear_model(self, dt: float, dtype: Any) -> tuple[Array, Array]:
        """``(A, B)`` of one axis, shapes (2, 2) and (2, 1) on ``(p, v)``: the model the MPC plans with."""


#: Registered plants (``double_integrator`` is the default of :class:`~jaxapf.config.VehicleConfig`).
PLANTS: Registry[Plant] = Registry("plant", on_register=DECLARE, role="vehicle model")


def register_plant(name: str, plant: Plant, *, replace: bool = False) -> Plant:
    """Register ``plant`` as ``plant = name`` (its gains are declared)."""
    return PLANTS.register(name, plant, replace=replace)
