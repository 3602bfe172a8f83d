r"""Velocity obstacles: the preferred velocity, corrected out of the obstacles' ORCA half-spaces.

Van den Berg, Guy, Lin and Manocha ("Reciprocal n-body collision avoidance", ISRR 2009; the RVO2
library) turn each obstacle into a half-space of permitted velocities, ORCA; for an agent facing
obstacles that do not react, the agent takes the whole avoidance on itself. Per obstacle ``o`` at
time ``t``, with the line of sight :math:`s = P(c_o(t) - p)`, the relative velocity
:math:`w = P(v - v_o)` (``P`` drops z for a cylinder, so a cylinder's constraint is horizontal)
and the combined radius :math:`R = ρ_o + r_{uav} + m` (gain ``vo_margin`` = m):

- The **velocity obstacle** truncated at the time horizon τ (gain ``vo_tau``) is the set of
  relative velocities that collide within τ, :math:`\{w : \exists\,t' \in (0, τ],\ |t' w - s| < R\}`:
  a cone from the origin around ``s`` with half-angle :math:`\arcsin(R/|s|)`, cut off by the disc of
  centre :math:`s/τ` and radius :math:`R/τ`. (Already overlapping, :math:`|s| \le R`, the cut-off
  disc uses τ = ``dt``, as RVO2 does, so the step pushes the UAV out.)
- ``u`` is the smallest change of ``w`` to the boundary of that set and ``n`` the boundary's
  outward normal there: on the cut-off disc :math:`n = \widehat{w - s/τ}`,
  :math:`u = (R/τ - |w - s/τ|)\,n`; on the cone, whose leg on the side of ``w`` is
  :math:`l = \cos α\,\hat s + \sin α\,e` (``e`` the unit part of ``w`` perpendicular to ``s``;
  for ``w`` along ``s``, the horizontal left normal of ``s``), :math:`u = (w\cdot l)\,l - w` and
  :math:`n = -\sin α\,\hat s + \cos α\,e`. In the horizontal plane this is RVO2's two-dimensional
  construction; for spheres it is the same construction in the plane of ``s`` and ``w``.
- The obstacle's **ORCA half-space** for a non-reactive obstacle is
  :math:`\{v' : (v' - (v + u))\cdot n \ge 0\}`; for another UAV of a swarm running the same
  stack (an obstacle flagged ``agent``, :mod:`jaxapf.datatypes.swarm`) it is
  :math:`\{v' : (v' - (v + u/2))\cdot n \ge 0\}`: each of the two takes half of the avoidance,
  ORCA's reciprocity.

The new velocity is the one nearest the preferred velocity that lies in every half-space and the
speed ball,

.. math:: v^* = \arg\min_{v'} |v' - v_{pref}|^2 \ \text{s.t.}\ (v' - v - u_o)\cdot n_o \ge 0\ \forall o,
          \quad |v'| \le v_{max}, \qquad v_{pref} = \mathrm{sat}_{v_{max}}(η F_{att}(p)),

solved exactly by :func:`jaxapf.projection.nearest_feasible` (fixed work: vmaps and differentiates;
RVO2 uses an incremental linear program instead). ``v_pref`` is the potential-field planners'
attractive flow (paper eq. 13's ``U_att``, gains ``k_att`` and ``η``, conic beyond ``att_cap``), so
without obstacles ``velocity_obstacle`` and ``basic`` fly the same reference. When the half-spaces
and the ball have no common point (crowded, or already inside an obstacle) the velocity used is the one
in the ball whose largest violation is least (nearest ``v_pref`` among those), as RVO2's fallback;
the step is counted as infeasible (its largest violation above
:data:`~jaxapf.projection.INFEASIBLE_TOL`; diagnostic ``vo_infeasible``, metric
``vo_infeasible_steps``), as the CBF filter counts its own. With ``sim.projection_rows`` that many
half-spaces are kept at a time (those that can bind soonest in the ball, then those the answer needs:
:func:`~jaxapf.projection.nearest_feasible`); a step whose answer a half-space left out still
violates by more than the kept ones is counted (``vo_truncated``, metric ``vo_truncated_steps``; its
largest violation then counts in ``vo_infeasible`` too when above the tolerance).

The reference for the MPC holds ``v*`` over the horizon, ``p_i = p + i Δt v*``, assembled like the
potential-field planners' (:func:`~jaxapf.planners.base.reference_states`); the receding horizon
re-solves every control step. The planner's state is the last step's ``vo_infeasible`` and
``vo_truncated`` flags (read by :meth:`VelocityObstacle.diagnostics`). Every valid obstacle counts,
static or moving, at its true position and velocity; a static obstacle is an agent of velocity zero.

Registered planners: ``velocity_obstacle`` (gains ``vo_tau``, ``vo_margin``, ``k_att``, ``eta``), and
``velocity_obstacle_unilateral``, the same but taking the whole avoidance against other UAVs too (ORCA
without its reciprocity: what reciprocity buys a swarm; one UAV flies it as ``velocity_obstacle``).
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING, Any

import jax.numpy as jnp
from jax import Array

from ..datatypes import ObstacleColumns, Obstacles, safe_norm
from ..datatypes.obstacles import TINY
from ..gains import GainSpec
from ..projection import INFEASIBLE_TOL, nearest_feasible, projection_metrics
from .apf import ETA, K_ATT, preferred_velocity
from .base import Planner, reference_states, register_planner
from .sight import line_of_sight

if TYPE_CHECKING:
    from ..config import SimConfig
    from ..gains import Gains

__all__ = ["VO_TAU", "VO_MARGIN", "VelocityObstacle", "orca_half_spaces"]

VO_TAU = GainSpec("vo_tau", 3.0, low=0.0, low_open=True, unit="s", symbol="τ",
                  doc="velocity obstacles: time horizon; only collisions within τ seconds constrain the velocity")
VO_MARGIN = GainSpec("vo_margin", 0.25, low=0.0, unit="m",
                     doc="velocity obstacles: margin added to the combined radius ρ_o + r_uav")

def _unit(a: Array) -> tuple[Array, Array]:
    """``(a / |a|, |a|)`` along the last axis, finite with a zero gradient at ``a = 0``."""
    length = safe_norm(a)
    return a / length[..., None], length


def orca_half_spaces(x: Array, t: Array, obstacles: ObstacleColumns, gains: "Gains",
                     sim: "SimConfig", reciprocal: bool = True) -> tuple[Array, Array]:
    """Rows ``n_o`` (M, 3, unit length) and bounds ``n_o·(v + u_o)`` (M,) of the ORCA half-spaces
    ``n_o·v' >= bound`` (module docstring); invalid slots give ``n = 0, bound = -1`` (always met).
    ``reciprocal``: another UAV of the swarm takes half of the avoidance (else all of it falls on this one)."""
    p, v = x[:3], x[3:]
    s = jnp.stack(line_of_sight(p, obstacles.position + obstacles.velocity * t, obstacles.cylinder), axis=-1)
    w = -jnp.stack(line_of_sight(v, obstacles.velocity, obstacles.cylinder), axis=-1)  # P(v - v_o)
    big_r = obstacles.radius + sim.vehicle.r_uav + gains.vo_margin
    s_hat, dist = _unit(s)
    overlapping = dist <= big_r
    tau = jnp.where(overlapping, sim.episode.dt, gains.vo_tau)
    # the cut-off disc: centre s/τ, radius R/τ
    cut = w - s / tau[:, None]
    cut_hat, cut_len = _unit(cut)
    along = jnp.sum(cut * s, axis=-1)
    on_disc = overlapping | ((along < 0.0) & (along * along > big_r * big_r * cut_len * cut_len))
    u_disc = (big_r / tau - cut_len)[:, None] * cut_hat
    # the cone's leg on the side of w
    perp = w - jnp.sum(w * s_hat, axis=-1, keepdims=True) * s_hat
    left = jnp.stack([-s_hat[:, 1], s_hat[:, 0], jnp.zeros_like(dist)], axis=-1)
    left = jnp.where(jnp.sum(left * left, axis=-1, keepdims=True) > 1e-12, left, jnp.asarray([1.0, 0.0, 0.0]))
    e = _unit(jnp.where(jnp.sum(perp * perp, axis=-1, keepdims=True) > 1e-12, perp, left))[0]
    sin_a = jnp.clip(big_r / dist, 0.0, 1.0)
    cos_a = jnp.sqrt(jnp.maximum(1.0 - sin_a * sin_a, TINY))
    leg = cos_a[:, None] * s_hat + sin_a[:, None] * e
    u_leg = jnp.sum(w * leg, axis=-1, keepdims=True) * leg - w
    n_leg = -sin_a[:, None] * s_hat + cos_a[:, None] * e
    u = jnp.where(on_disc[:, None], u_disc, u_leg)
    n = jnp.where(on_disc[:, None], cut_hat, n_leg)
    if reciprocal and obstacles.agent is not None:  # another UAV of the swarm takes its half (ORCA's reciprocity)
        u = u * jnp.where(obstacles.agent, 0.5, 1.0)[:, None]
    bound = jnp.sum(n * (v + u), axis=-1)
    valid = obstacles.valid
    return jnp.where(valid[:, None], n, 0.0), jnp.where(valid, bound, -1.0)


@dataclasses.dataclass(frozen=True)
class VelocityObstacle(Planner):
    """velocity obstacles (ORCA, van den Berg et al. 2009): the goal-seeking velocity avoiding every collision within τ

    The velocity nearest the preferred one in every obstacle's ORCA half-space and the speed ball
    (module docstring). ``reciprocal``: another UAV of a swarm takes half of the avoidance (ORCA);
    without it this UAV takes all of it, as against a passive obstacle (``velocity_obstacle_unilateral``).
    """

    color: str | None = "tab:brown"
    reciprocal: bool = True
    linestyle: str | None = "-"
    metrics = projection_metrics("vo", "the velocity obstacles' half-spaces", "the speed ball", "0 for other planners")

    @property
    def description(self) -> str:
        """One line for ``jaxapf list planners`` (the variant says what it lacks)."""
        return super().description if self.reciprocal else (
            "velocity obstacles taking the whole avoidance against other UAVs too: ORCA without its reciprocity "
            "(a variant; one UAV alone flies it as velocity_obstacle)")

    @property
    def gains(self) -> tuple[GainSpec, ...]:
        return (VO_TAU, VO_MARGIN, K_ATT, ETA)

    @property
    def reads(self) -> tuple[str, ...]:
        return ("att_cap", "reference_velocity")

    def init(self, scenario: Any, gains: "Gains", sim: "SimConfig", horizon: int) -> Array:
        """The state: whether the last step's half-spaces and speed ball had no common point, and whether
        a half-space left out (``sim.projection_rows``) was violated at its answer."""
        return jnp.zeros((2,), bool)

    def diagnostics(self, state: Array) -> dict[str, Array]:
        return {"vo_infeasible": state[0], "vo_truncated": state[1]}

    def velocity(self, x: Array, t: Array, goal: Array, obstacles: ObstacleColumns, gains: "Gains",
                 sim: "SimConfig") -> tuple[Array, Array]:
        """``(v*, largest violation of the half-spaces, exact)`` at the state ``x`` and time ``t``
        (:func:`~jaxapf.projection.nearest_feasible`)."""
        preferred = preferred_velocity(x, goal, gains, sim)
        n, bound = orca_half_spaces(x, t, obstacles, gains, sim, self.reciprocal)
        return nearest_feasible(preferred, n, bound, sim.vehicle.v_max, "ball", sim.planner.projection_rows)

    def reference(self, state: Any, x: Array, t: Array, goal: Array, obstacles: Obstacles | ObstacleColumns,
                  gains: "Gains", sim: "SimConfig", horizon: int) -> tuple[Array, Any]:
        """``v*`` held over the horizon (module docstring); the state is whether this step was infeasible
        and whether it was truncated."""
        velocity, worst, exact = self.velocity(x, t, goal, obstacles.columns(), gains, sim)
        steps = jnp.arange(1, horizon + 1, dtype=x.dtype)[:, None]
        points = x[:3] + steps * sim.episode.dt * velocity
        return (reference_states(x, points, jnp.broadcast_to(velocity, points.shape), sim),
                jnp.stack([worst > INFEASIBLE_TOL, ~exact]))


register_planner("velocity_obstacle", VelocityObstacle())
register_planner("velocity_obstacle_unilateral", VelocityObstacle(color="tab:pink", linestyle="--", reciprocal=False))
