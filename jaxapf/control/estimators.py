r"""Disturbance estimators: offset-free tracking for the MPC (``estimator = "..."``).

The MPC plans with the disturbance-free double integrator, so a steady push ``d`` (wind) leaves the
UAV short of its goal by the offset at which the potential's pull balances ``d``. An estimator keeps
an estimate ``d̂`` of the acceleration the plant adds to its command, and the closed loop uses the
disturbance-augmented model of offset-free MPC (Pannocchia & Rawlings 2003, "Disturbance models for
offset-free model-predictive control", AIChE J.): the MPC plans the *total* acceleration
``a = u + d̂`` with the command box shifted to ``[-a_max + d̂, a_max + d̂]``, the safety filter acts on
that total acceleration (what moves the UAV relative to the obstacles), and the plant gets the
command ``u = a - d̂`` (clipped to the box). At the goal the plan is ``a = 0``, so the command is
``u = -d̂``: the steady state has no offset once ``d̂ = d``.

``observer`` (:class:`Observer`): the acceleration residual of the last step,
``r_k = (v_k - v_{k-1}) / Δt - u_{k-1}``, low-pass filtered,

.. math:: \hat d_k = \hat d_{k-1} + α (r_k - \hat d_{k-1}), \qquad α = 1 - e^{-Δt/τ}

(``dob_tau`` = τ). For the double integrator, a constant ``d`` and exact velocities ``r_k = d``, so
the error obeys ``d - \hat d_k = (1 - α)(d - \hat d_{k-1})``: it decays geometrically with time
constant τ. ``integral`` (:class:`Integral`): integral action on the position, the estimate driven
by the miss of the one-step prediction ``p̂_k = p_{k-1} + Δt v_{k-1} + Δt²(u_{k-1} + \hat d_{k-1})/2``,
``\hat d_k = \hat d_{k-1} + k_i (p_k - p̂_k)`` (``k_i`` = ``dob_ki`` [1/s²]): for a constant ``d`` the
miss is ``Δt²(d - \hat d_{k-1})/2``, so the same geometric decay with ``α = k_i Δt²/2``. ``none``
(:class:`NoEstimator`, the default) estimates nothing and changes nothing in the program.
"""

from __future__ import annotations

import abc
import dataclasses
from typing import TYPE_CHECKING, Any, ClassVar

import jax.numpy as jnp
from jax import Array

from ..gains import GainSpec
from ..registry import Registry
from ..stage import DECLARE, Stage

if TYPE_CHECKING:
    from ..config import SimConfig
    from ..datatypes import Scenario
    from ..gains import Gains

__all__ = ["Estimator", "NoEstimator", "Observer", "Integral", "ESTIMATORS", "register_estimator"]


class Estimator(Stage, abc.ABC):
    """Estimates the acceleration a disturbance adds to the command (a :class:`~jaxapf.stage.Stage`).
    ``active = False`` (``none``) compiles no estimate into the loop."""

    active: ClassVar[bool] = True

    def init(self, scenario: "Scenario", gains: "Gains", sim: "SimConfig") -> Any:
        """At rest at the start, nothing estimated: ``(x_{-1}, u_{-1}, d̂)``."""
        dtype = scenario.start.dtype
        return jnp.concatenate([scenario.start, jnp.zeros(3, dtype)]), jnp.zeros(3, dtype), jnp.zeros(3, dtype)

    def __call__(self, state: Any, x: Array, gains: "Gains", sim: "SimConfig") -> tuple[Array, dict[str, Array]]:
        """``d̂_k`` (3,) at the sensed state ``x = [p, v]`` (6,) and diagnostics; :meth:`advance` then
        records the step's command."""
        previous, command, estimate = state
        return self.update(previous, command, estimate, x, gains, sim.episode.dt), {}

    @abc.abstractmethod
    def update(self, previous: Array, command: Array, estimate: Array, x: Array, gains: "Gains", dt: float) -> Array:
        """The new estimate from the last state ``previous``, its command and estimate, and the state ``x``."""

    def advance(self, x: Array, command: Array, estimate: Array) -> Any:
        """The state after a step: its sensed state, its command and its estimate."""
        return x, command, estimate


@dataclasses.dataclass(frozen=True)
class NoEstimator(Estimator):
    """No estimator: the MPC plans with the disturbance-free model (the paper's stack)."""

    active: ClassVar[bool] = False

    def init(self, scenario: Any, gains: Any, sim: Any) -> Any:
        return ()

    def update(self, previous: Array, command: Array, estimate: Array, x: Array, gains: Any, dt: float) -> Array:
        raise NotImplementedError("the loop does not call an inactive estimator")


DOB_TAU = GainSpec("dob_tau", 0.5, low=0.0, low_open=True, unit="s", symbol="τ_d", tunable=False,
                   doc="observer: time constant of the low-pass filter on the acceleration residual")
DOB_KI = GainSpec("dob_ki", 20.0, low=0.0, low_open=True, unit="1/s²", symbol="k_i", tunable=False,
                  doc="integral action: gain on the one-step position miss (alpha = k_i dt²/2, below 1)")


@dataclasses.dataclass(frozen=True)
class Observer(Estimator):
    """Acceleration-disturbance observer: the last step's acceleration residual, low-pass filtered with
    time constant ``dob_tau`` (offset-free MPC)."""

    gains: ClassVar[tuple[GainSpec, ...]] = (DOB_TAU,)

    def update(self, previous: Array, command: Array, estimate: Array, x: Array, gains: "Gains", dt: float) -> Array:
        residual = (x[3:] - previous[3:]) / dt - command
        alpha = 1.0 - jnp.exp(-dt / gains.dob_tau)
        return estimate + alpha * (residual - estimate)


@dataclasses.dataclass(frozen=True)
class Integral(Estimator):
    """Integral action: the estimate integrates the miss of the one-step position prediction with gain
    ``dob_ki`` (offset-free MPC)."""

    gains: ClassVar[tuple[GainSpec, ...]] = (DOB_KI,)

    def update(self, previous: Array, command: Array, estimate: Array, x: Array, gains: "Gains", dt: float) -> Array:
        predicted = previous[:3] + dt * previous[3:] + 0.5 * dt * dt * (command + estimate)
        return estimate + gains.dob_ki * (x[:3] - predicted)


#: Registered estimators: the values of ``estimator`` (default ``none``).
ESTIMATORS: Registry[Estimator] = Registry("estimator", on_register=DECLARE,
                                           role="disturbance estimator for offset-free tracking")


def register_estimator(name: str, estimator: Estimator, *, replace: bool = False) -> Estimator:
    """Register ``estimator`` as ``estimator = name`` (its gains are declared)."""
    return ESTIMATORS.register(name, estimator, replace=replace)


register_estimator("none", NoEstimator())
register_estimator("observer", Observer())
register_estimator("integral", Integral())
