r"""Potential-field planners: N prediction points by a saturated gradient flow (SPEC 4).

Starting from the current ``(p_0, v_0) = (p, v)`` at time ``t``:

.. math::
   F_i = -\nabla_p\Big[U_{att}(p_i) + \sum_o \omega\,U_{rep}(p_i, v_i, p_o(t_i), v_o)\Big]
         + \sum_j T_j(p_i, v_i, t_i), \quad
   u_i = \mathrm{sat}_{v_{max}}(\eta F_i), \quad
   p_{i+1} = p_i + \Delta t\, u_i, \quad v_{i+1} = u_i

with obstacles extrapolated at constant velocity, ``p_o(t_i) = p_o + v_o (t + i Δt)``, which makes
the scheme predictive; ``sat`` clips the norm. ω is the planner's :class:`~.weights.Weight`; the
``T_j`` are extra :class:`ForceTerm`\ s that are not gradients of a potential (none for the paper's
methods). The MPC reference is ``(P_pred, 0)`` (the paper's zero velocity reference) or, with
``PlannerConfig.reference_velocity``, ``(P_pred, [v, u_0, …, u_{N-1}])``.

The paper's three methods are ``APF(Basic())``, ``APF(Direction())`` and
``APF(DirectionVelocity())``, registered as ``basic``, ``direction`` and ``direction_velocity``;
:func:`fused` flies several potential-field methods in one program (the accelerator policy).
"""

from __future__ import annotations

import abc
import dataclasses
from typing import TYPE_CHECKING, Any, ClassVar

import jax
import jax.numpy as jnp
from jax import Array

from ..datatypes import ObstacleColumns, Obstacles, safe_norm
from ..gains import GainSpec, declare_gains
from ..validation import ConfigError
from .base import PLANNERS, Planner, reference_states, register_planner
from .potentials import attractive_potential, total_force
from .weights import GAMMA, Basic, Chosen, Direction, DirectionVelocity, K, Normalised, Weight

if TYPE_CHECKING:
    from ..config import SimConfig
    from ..gains import Gains

__all__ = ["K_REP", "D_S", "K_ATT", "ETA", "ForceTerm", "APF", "saturate", "FUSED", "fusable", "fused"]

K_REP = GainSpec("k_rep", 10.0, low=0.0, low_open=True, doc="repulsive gain k_rep (paper eq. 13)")
D_S = GainSpec("d_s", 4.0, low=0.0, low_open=True, unit="m", doc="influence distance d_s (paper eq. 13)")
K_ATT = GainSpec("k_att", 1.0, low=0.0, low_open=True, doc="attractive gain, U_att = ½ k_att |p - g|²")
ETA = GainSpec("eta", 0.5, low=0.0, low_open=True, unit="m/s per unit force", symbol="η",
               doc="step gain η of the reference flow u = η F")
#: The gains every potential-field planner reads.
APF_GAINS = (K_REP, D_S, K_ATT, ETA)


class ForceTerm(abc.ABC):
    """An extra force of the flow that is not the gradient of a potential (e.g. a vortex).
    Subclasses are frozen dataclasses.

    Attributes:
      gains: the gains it reads (declared when a planner using it is registered).
    """

    gains: ClassVar[tuple[GainSpec, ...]] = ()

    @abc.abstractmethod
    def __call__(self, p: Array, v: Array, t: Array, goal: Array, obstacles: ObstacleColumns, gains: "Gains",
                 sim: "SimConfig") -> Array:
        """The force (3,) at position ``p``, velocity ``v``, time ``t`` (obstacles at ``t = 0``,
        component-first; they move as ``position + velocity · t``)."""


def saturate(u: Array, limit: float) -> Array:
    """Scale ``u`` down to norm ``limit`` if it is longer (direction kept)."""
    return u * jnp.minimum(1.0, limit / safe_norm(u))


def preferred_velocity(x: Array, goal: Array, gains: "Gains", sim: "SimConfig") -> Array:
    """``sat_{v_max}(η F_att)`` at the state ``x``: the attractive flow alone, the velocity the planners that
    avoid by constraints (velocity obstacles, the keep-out MPC) would take without obstacles."""
    attraction = -jax.grad(attractive_potential)(x[:3], goal, gains.k_att, sim.planner.att_cap)
    return saturate(gains.eta * attraction, sim.vehicle.v_max)


def _unique(specs: tuple[GainSpec, ...]) -> tuple[GainSpec, ...]:
    return tuple({s.name: s for s in specs}.values())


@dataclasses.dataclass(frozen=True)
class APF(Planner):
    """A potential-field planner: the saturated gradient flow of ``U_att + Σ ω U_rep`` (module docstring).

    Attributes:
      weight: the repulsive weight ω.
      terms: extra forces added to ``-∇U`` in the flow.
      description: one line for ``jaxapf list planners`` (default: the weight's docstring).
    """

    weight: Weight
    terms: tuple[ForceTerm, ...] = ()
    description: str = ""
    color: str | None = None
    linestyle: str | None = None

    @property
    def gains(self) -> tuple[GainSpec, ...]:
        return _unique(self.weight.gains + tuple(g for term in self.terms for g in term.gains) + APF_GAINS)

    @property
    def reads(self) -> tuple[str, ...]:
        convention = ("convention",) if self.weight.uses_convention else ()
        return convention + ("d_min", "eps_v", "att_cap", "reference_velocity")

    def force(self, p: Array, v: Array, t: Array, goal: Array, obstacles: ObstacleColumns, gains: "Gains",
              sim: "SimConfig") -> Array:
        """The flow's force ``F`` (3,) at ``(p, v)`` and time ``t``."""
        cfg = sim.planner
        force = total_force(p, v, t, goal, obstacles, gains, method=self.weight, convention=cfg.convention,
                            r_uav=sim.vehicle.r_uav, d_min=cfg.d_min, eps_v=cfg.eps_v, att_cap=cfg.att_cap)
        for term in self.terms:
            force = force + term(p, v, t, goal, obstacles, gains, sim)
        return force

    def reference(self, state: Any, x: Array, t: Array, goal: Array, obstacles: Obstacles | ObstacleColumns,
                  gains: "Gains", sim: "SimConfig", horizon: int) -> tuple[Array, Any]:
        """MPC reference states (horizon+1, 6) for ``x(k..k+N)`` from the flow; the state is unchanged.

        ``obstacles`` in either layout; a closed loop passes :class:`~jaxapf.datatypes.ObstacleColumns`,
        converted once per episode, so no control step transposes the field again.
        """
        obstacles = obstacles.columns()
        dt = sim.episode.dt

        def flow(carry, i):
            p, v = carry
            u = saturate(gains.eta * self.force(p, v, t + i * dt, goal, obstacles, gains, sim), sim.vehicle.v_max)
            return (p + dt * u, u), (p + dt * u, u)

        _, (points, flows) = jax.lax.scan(flow, (x[:3], x[3:]), jnp.arange(horizon, dtype=x.dtype))
        return reference_states(x, points, flows, sim), state


#: What joins the methods of a fused program's name: ``basic+direction+direction_velocity``.
FUSED = "+"


def fusable(planner: Planner) -> bool:
    """Whether ``planner`` can fly in a fused program (:func:`fused`): a potential-field planner that differs
    from the others only in its weight (no extra force terms)."""
    return type(planner) is APF and not planner.terms


def fused(name: str) -> APF:
    """The planner of a fused program ``name`` (methods joined by :data:`FUSED`): the potential-field flow whose
    weight is each method's own, chosen per episode by the gain ``weight_choice`` (its method's position in
    ``name``), so that methods differing only in their weight share one compiled program. Each must be
    :func:`fusable`."""
    planners = [PLANNERS.get(m, "method") for m in name.split(FUSED)]
    odd = [m for m, p in zip(name.split(FUSED), planners) if not fusable(p)]
    if odd or len(planners) < 2:
        raise ConfigError(f"method = {name!r}: a fused program flies two or more potential-field planners without "
                          f"extra force terms{'; not ' + ', '.join(odd) if odd else ''}")
    return APF(Chosen(tuple(p.weight for p in planners)), description=f"the weights of {', '.join(name.split(FUSED))}")


# The paper's gains, in the order of its tables, then its three methods.
declare_gains(GAMMA, K, *APF_GAINS, kind="planner")
register_planner("basic", APF(Basic(), color="tab:orange", linestyle=":",
                              description="the classical potential field: ω = 1 (paper eq. 13)"))
register_planner("direction", APF(Direction(), color="tab:purple", linestyle="--",
                                  description="direction-weighted: ω = 1 + γ(1 + cos θ)/2 (paper eq. 15)"))
register_planner("direction_velocity", APF(DirectionVelocity(), color="tab:blue", linestyle="-",
                                           description="the paper's proposal: ω = [1 + γ(1 + cos θ)/2](2 + k tanh c) "
                                                       "(paper eq. 19)"))
register_planner("direction_normalised", APF(Normalised(Direction()), color="tab:pink", linestyle="--",
                                             description="direction weight divided by its abeam value 1 + γ/2: "
                                                         "shape without strength"))
register_planner("direction_velocity_normalised", APF(Normalised(DirectionVelocity()), color="tab:cyan",
                                                      linestyle="-.", description="the paper's weight divided by its "
                                                      "abeam, non-closing value (1 + γ/2)·2"))
