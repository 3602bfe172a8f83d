r"""Velocity obstacles: the preferred velocity, corrected out of the obstacles' ORCA half-spaces.

Van den Berg, Guy, Lin and Manocha ("Reciprocal n-body collision avoidance", ISRR 2009; the RVO2
library): each obstacle becomes a half-space of permitted velocities (ORCA); the reference holds the
velocity nearest the attractive flow ``sat(η F_att)`` within every half-space and the speed ball over
the horizon, solved exactly by :func:`jaxapf.projection.nearest_feasible` (RVO2's least-violation
velocity where none fits, counted as ``vo_infeasible``). Against a non-reactive obstacle the UAV takes
the whole avoidance; against another UAV of a swarm (an obstacle flagged ``agent``) half of it, ORCA's
reciprocity. The construction (the truncated cone, the smallest change ``u``, its normal ``n``):
docs/spec.md, section 3, "velocity obstacles".

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
